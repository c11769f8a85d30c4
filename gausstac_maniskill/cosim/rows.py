"""Where a scene's particles are, in the rows the splat camera reads (:class:`SceneRows`, part
of :class:`~.scene.GaussTacSim`): first the equilibrium pads' (from their solution), then the MPM
world's; sleeping pads carried by their links. Units: metres."""
from __future__ import annotations

import numpy as np


class SceneRows:
    """The particle rows of a :class:`~.scene.GaussTacSim` (a part of it: the pads and the world
    are the scene's)."""

    def particles(self, index: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """World positions [P, 3] and F [P, 3, 3] (float32) of every particle of the scene, for
        rendering: first the equilibrium pads' (pad after pad, from their solution:
        :attr:`solved_rows` rows), then every particle of the world (MPM pads, soft objects, in
        group order; row ``solved_rows + i`` is the world's particle i), sleeping pads carried by
        their links. With ``index`` ([P'] ascending rows) only those particles, [P', 3] and
        [P', 3, 3]. (The splat camera reads the world's on the device instead: :meth:`carry_rows`,
        :meth:`pad_carries`, :func:`gausstac_maniskill.mpm.gather.carried_frames`.)"""
        n, fem = self.solved_rows, self.solvers["fem"]
        if self._world_particles():
            x, F = self.world.positions(), self.world.deformation_gradients()
        else:
            x, F = np.zeros((0, 3), np.float32), np.zeros((0, 3, 3), np.float32)
        rows = np.arange(n + len(x)) if index is None else np.asarray(index)
        k = int(np.searchsorted(rows, n))  # rows[:k]: the equilibrium pads', rows[k:]: the world's
        x = np.concatenate([np.zeros((k, 3), np.float32), x if index is None else x[rows[k:] - n]])
        F = np.concatenate([np.zeros((k, 3, 3), np.float32), F if index is None else F[rows[k:] - n]])
        self.solvers["mpm"].fill_particles(rows[k:] - n, x[k:], F[k:])  # sleeping pads carried by their links
        fem.fill_particles(rows[:k], x[:k], F[:k])  # from their solution
        return x, F

    @property
    def solved_rows(self) -> int:
        """The equilibrium pads' particle count: the first rows of :meth:`particles` (the world's
        particles follow)."""
        return self.solvers["fem"].num_particles

    def particle_rows(self, name: str) -> tuple[int, int]:
        """Rows ``start:stop`` of pad or soft object ``name`` among :meth:`particles`."""
        fem = self.solvers["fem"]
        if name in fem:
            return fem.rows(name)
        g = self.group(name)
        return self.solved_rows + g.start, self.solved_rows + g.stop

    def _world_particles(self) -> int:
        """The world's particle count (every env's, in a shared world)."""
        return max((g.stop for g in self.world.groups), default=0)

    def rest_positions(self) -> np.ndarray:
        """[P, 3] float32 positions [m] of the rows of :meth:`particles` as held now, sleeping
        pads where they fell asleep (the equilibrium pads' from their solution, the world's as
        it holds them): what the splat scene binds its soft Gaussians to, at rest."""
        x = self.world.positions() if self._world_particles() else np.zeros((0, 3), np.float32)
        fem = self.solvers["fem"]
        return np.concatenate([np.zeros((0, 3), np.float32)] + [fem.particles(name)[0] for name in fem.names] + [x])

    def equilibrium_frames(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The frames of the rows ``rows`` ([P'] ascending rows of :meth:`particles`) that lie on
        pads solved at equilibrium (``pad_solver="fem"``): (their positions in ``rows`` [k],
        their frames (F | x) [k, 3, 4] float32, world frame, from :meth:`pad_particles`). The
        splat camera draws these pads with them."""
        rows = np.asarray(rows)
        return self.solvers["fem"].frames(rows[:int(np.searchsorted(rows, self.solved_rows))])

    def _carry(self, name: str) -> np.ndarray | None:
        """The rigid motion [4, 4] of pad ``name``'s link since the pad fell asleep (its particles
        stay where they were), or None while it is awake."""
        return self.pad_solver_of(name).carry(name)

    def carry_rows(self, index: np.ndarray) -> np.ndarray:
        """[P'] int32: for each row of :meth:`particles` in ``index`` ([P'] ascending), the row of
        :meth:`pad_carries` that carries it: 1 + the number of its pad, 0 for a soft object's."""
        index = np.asarray(index)
        rows = np.zeros(len(index), np.int32)
        for i, name in enumerate(self.pads):
            lo, hi = np.searchsorted(index, self.particle_rows(name))
            rows[lo:hi] = 1 + i
        return rows

    def pad_carries(self) -> np.ndarray:
        """[1 + pads, 3, 4] float32 rigid motions that move the particles to where the renderer
        draws them: row 0 the identity; row 1 + i pad i's link motion since it fell asleep
        (:meth:`_carry`), the identity while it is awake."""
        out = np.zeros((1 + len(self.pads), 3, 4), np.float32)
        out[:, :, :3] = np.eye(3)
        for i, name in enumerate(self.pads):
            D = self._carry(name)
            if D is not None:
                out[1 + i] = D[:3]
        return out
