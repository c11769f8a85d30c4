"""Pads solved at equilibrium after every step: one
:class:`~gausstac_maniskill.fem.sensor.EquilibriumPad` (linear cut-cell FEM, no pseudo-mass, no
time step) per pad.

At the step's end each awake pad meets the rigid objects within reach of its surface points
(one element; each point meets the nearest) and the push of soft objects: each pad's link mesh
is a collider of the world that the soft objects meet, shaped as the pad was last solved, and
the reaction to their particles' contact impulses on it loads the pad (a staggered coupling,
``fem_model="linear"`` only). A pad with no object within the sleep margin is at rest and reads
zero maps. The pads pass the contact forces to their links and the opposite to the objects
(:meth:`EquilibriumPads.object_wrench`, :meth:`EquilibriumPads.link_contacts`). The pads have
no particles in the MPM world: their particles, numbered pad after pad (:meth:`EquilibriumPads.rows`),
are read from their solution for rendering (:meth:`EquilibriumPads.frames`). Units: SI.
"""
from __future__ import annotations

import time

import numpy as np
import torch

from ..errors import ConfigError
from ..fem.sensor import EquilibriumPad
from ..tactile import pad_mesh
from ..tactile.extract import TaxelBinning, tactile_maps
from .interface import PadSolver

__all__ = ["EquilibriumPads", "add_contact"]


def add_contact(rows: dict, name, row: np.ndarray) -> None:
    """Add a :meth:`GaussTacSim.link_contacts` row [7] (force, torque, indentation) to ``rows``
    under ``name``: forces and torques add, the deeper indentation stands."""
    if name in rows:
        row = np.concatenate([rows[name][:6] + row[:6], [max(rows[name][6], row[6])]])
    rows[name] = row


class EquilibriumPads(PadSolver):
    """The scene's equilibrium pads (module docstring), solved on the host after the world's step.

    Attributes:
        pads: pad name -> its :class:`~gausstac_maniskill.fem.sensor.EquilibriumPad`.
        solve_time: wall time [s] of the last step's solves.
    """

    kind = "fem"

    def __init__(self, scene, settings):
        super().__init__(scene, settings)
        self.pads: dict[str, EquilibriumPad] = {}
        # pad name -> index of the collider its link mesh is for soft objects, and its SDF at rest
        self.surface_colliders: dict[str, int] = {}
        self.surface_rest: dict[str, np.ndarray] = {}
        self.binning: dict[str, TaxelBinning] = {}
        self._zero_maps: dict[str, dict] = {}  # pad -> its maps at rest (zeros), by shape
        self._maps: dict[str, dict] = {}  # pad -> its maps of the last step (built on first read)
        self.solve_time = 0.0

    def add(self, name: str) -> None:
        """Pad ``name`` as an :class:`EquilibriumPad` (no particles in the world: it meets the
        world's objects through the solver, and soft objects through its surface collider)."""
        self.pads[name] = EquilibriumPad(self._pad(name), model=self.settings.fem_model,
                                         precompute=self.settings.fem_precompute)
        self.names.append(name)
        self.awake[name] = True

    def share_bodies(self, other: "EquilibriumPads") -> None:
        """Use ``other``'s bodies (the same pads in another env of a batch): one factor and one
        compliance per pad for every env (:meth:`EquilibriumPad.share_body`)."""
        for name, fp in self.pads.items():
            fp.share_body(other.pads[name])

    def prepare(self) -> None:
        """Build every pad's body now: assemble its stiffness and compute or load its surface
        compliance and its maps' response (otherwise done in the first step that brings an
        object within the sleep margin)."""
        for fp in self.pads.values():
            fp.body  # noqa: B018 (built on first access)

    def clear(self) -> list[str]:
        """Give up every pad (the scene's pads become MPM pads); returns their names."""
        names = list(self.names)
        self.pads.clear()
        self.names.clear()
        self.awake.clear()
        self._maps = {}
        return names

    @property
    def touched(self) -> bool:
        """Whether any pad has a solution (something touched it since it was last at rest)."""
        return any(fp.result is not None for fp in self.pads.values())

    # ------------------------------------------------------------------ soft objects
    def meet_soft_object(self, name: str, auto: bool) -> bool:
        """Soft object ``name`` joins the scene: the pads meet it through their surface
        colliders (True), or, finite-strain pads with ``solver="auto"`` that touched nothing yet,
        must become MPM pads (False). A :class:`ConfigError` where finite-strain pads cannot."""
        models = sorted({fp.model for fp in self.pads.values()} - {"linear"})
        if models and auto and not self.touched:
            return False
        if models:
            raise ConfigError(f"add_soft_object({name!r}): pads solved at equilibrium meet soft objects with "
                              f"fem_model='linear' only (these are {models[0]!r}"
                              f"{' and have touched something already' if auto else ''}); "
                              f"use fem_model='linear' or pad_solver='mpm'")
        if self.pads:
            self._add_surface_colliders()
        return True

    def _add_surface_colliders(self) -> None:
        """Each pad's link mesh as a rigid collider of the world, moving with its link, for the
        soft objects to meet (friction ``settings.soft_friction``): their push on it loads the
        pad (:meth:`_soft_load`), and it takes the pad's shape before each step
        (:meth:`_shape_surface_colliders`)."""
        from ..geometry.colliders import MeshCollider

        scene = self.scene
        for name in self.names:
            if name in self.surface_colliders:
                continue
            pad = self._pad(name)
            T = scene.link_pose(pad.spec.link)
            mesh = pad_mesh(pad.spec, scene.urdf)
            col = MeshCollider(pose=T, friction=scene.settings.soft_friction, name=f"surface of pad {name!r}",
                               mesh=mesh, sdf_dx=min(pad.spacing, float(np.max(mesh.extents)) / 48.0))
            self.surface_colliders[name] = scene.world.add_collider(col, env=scene.env)
            self.surface_rest[name] = col.sdf  # (read-only, shared)

    def _shape_surface_colliders(self) -> None:
        """Each surface collider takes its pad's shape for the next step: its SDF lowered by the
        surface's outward normal offset at the nearest surface point, φ − s (s follows the last
        solved shape, relaxed: :meth:`~gausstac_maniskill.fem.sensor.EquilibriumPad.relax_surface`)."""
        world = self.scene.world
        for name, c in self.surface_colliders.items():
            fp, rest = self.pads[name], self.surface_rest[name]
            col = world.colliders[c]
            offset = fp.relax_surface()
            if fp.result is None:
                if col.sdf is not rest:
                    world.set_collider_sdf(c, rest)
                continue
            nearest = fp.grid_nearest_points(col.sdf_origin, col.sdf_dx, rest.shape)
            world.set_collider_sdf(c, rest - offset[nearest].reshape(rest.shape))

    def _soft_load(self, name: str, T: np.ndarray) -> np.ndarray | None:
        """[S, 3] link-frame load [N] the soft objects put on pad ``name`` in the last step (the
        reaction to their particles' contact with its surface collider), or None."""
        c = self.surface_colliders.get(name)
        if c is None:
            return None
        world, w = self.scene.world, self.scene.world_name
        xs, fs = [], []
        for g in self.scene.soft_objects:
            touch = world.contact_collider(w(g)) == c
            if touch.any():
                xs.append(world.positions(w(g))[touch])
                fs.append(-world.contact_forces(w(g))[touch])  # on the pad: the opposite
        if not xs:
            return None
        return self.pads[name].soft_load(np.concatenate(xs), np.concatenate(fs), T)

    # ------------------------------------------------------------------ stepping
    def after_link_poses(self) -> None:
        for name, c in self.surface_colliders.items():
            self.scene.world.set_collider_pose(c, self.scene.link_pose(self._pad(name).spec.link))
        self._shape_surface_colliders()

    def set_near(self, name: str, near: bool) -> None:
        if not near:  # away from every object the pad is at rest
            self.pads[name].release()
        self.awake[name] = near

    def end_step(self) -> None:
        """Each awake pad against the rigid objects within reach of its surface points (one
        element), each point meeting the nearest of them
        (:class:`~gausstac_maniskill.fem.indenters.Indenters`), and the soft objects' push. A
        pad with neither is at rest."""
        from ..geometry.colliders import signed_distance

        if self.pads:
            world, objects = self.scene.world, self.scene.rigid_objects
            t0 = time.perf_counter()
            for name, fp in self.pads.items():
                if not self.awake[name]:
                    continue
                T = self.scene.link_pose(fp.pad.spec.link)
                body = fp.body
                local = body.points if fp.result is None else body.points + fp.result.displacement
                pts = local @ T[:3, :3].T + T[:3, 3]
                near = {obj: world.colliders[i] for obj, i in sorted(objects.items())
                        if float(signed_distance(world.colliders[i], pts)[0].min()) < body.body.size}
                load = self._soft_load(name, T)
                if near or load is not None:
                    fp.solve(near, T, load)
                else:
                    fp.release()
            self.solve_time = time.perf_counter() - t0
        self._maps = {}

    # ------------------------------------------------------------------ readout
    def tactile(self) -> dict:
        for name in self.names:
            if name not in self._maps:
                self._maps[name] = self._pad_maps(name)
        return {name: self._maps[name] for name in self.names}

    def _pad_maps(self, name: str) -> dict[str, torch.Tensor]:
        """The maps of pad ``name``, on the Taichi arch's device: for a linear pad with its full
        compliance, one matrix times its contact forces (:meth:`EquilibriumPad.tactile_maps`);
        else :func:`~gausstac_maniskill.tactile.extract.tactile_maps` of its particles' state
        (:meth:`EquilibriumPad.particle_state`: one solve of the body). Exact zeros while
        nothing touches it (its equilibrium is then its rest shape)."""
        from .. import backend

        fp, pad = self.pads[name], self._pad(name)
        if name not in self.binning:
            self.binning[name] = TaxelBinning.for_pad(pad)
        T = self.scene.link_pose(pad.spec.link)
        if fp.result is None and name in self._zero_maps:
            return {k: v.clone() for k, v in self._zero_maps[name].items()}
        maps = fp.tactile_maps(self.binning[name])
        if maps is None:
            x, _, sigma, f = fp.particle_state(T)
            maps = tactile_maps(pad, self.binning[name], x, T, f, sigma)
        device = backend.torch_device()
        maps = {k: v.to(device) for k, v in maps.items()}
        if fp.result is None:  # at rest: zeros (their shapes and dtypes kept for the next time)
            self._zero_maps[name] = {k: torch.zeros_like(v) for k, v in maps.items()}
            maps = {k: v.clone() for k, v in self._zero_maps[name].items()}
        return maps

    def contact_forces(self, name: str) -> np.ndarray:
        return self.pads[name].particle_state(self.scene.link_pose(self._pad(name).spec.link))[3]

    def stress_force(self, name: str) -> np.ndarray:
        """The elements' internal forces off the bond (:meth:`EquilibriumPad.stress_force`):
        equal to the contact force at equilibrium by construction."""
        p = self._pad(name)
        return p.sensor_frame[:3, :3].T @ self.pads[name].stress_force()

    def particles(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        x, F, _, _ = self.pads[name].particle_state(self.scene.link_pose(self._pad(name).spec.link))
        return x.astype(np.float32), F.astype(np.float32)

    def object_wrench(self, obj, origin, f, tau):
        for fp in self.pads.values():
            if obj in fp.holders:
                x, fc = fp.contact_points(self.scene.link_pose(fp.pad.spec.link), obj)
                f, tau = f - fc.sum(0), tau - np.cross(x - origin, fc).sum(0)
        return f, tau

    def link_wrench(self, link, f, tau):
        for row in self.link_contacts(link).values():
            f, tau = f + row[:3], tau + row[3:6]
        return f, tau

    def link_contacts(self, link: str) -> dict:
        out: dict = {}
        for fp in self.pads.values():
            if fp.pad.spec.link != link or not fp.touching:
                continue
            T = self.scene.link_pose(link)
            for obj in fp.holders:
                x, fc = fp.contact_points(T, obj)
                add_contact(out, obj, np.concatenate([fc.sum(0), np.cross(x - T[:3, 3], fc).sum(0),
                                                      [fp.indentation(obj)]]))
            x, fc = fp.load_points(T)  # soft objects' push (key None, as the MPM pads' other field)
            if len(x):
                add_contact(out, None, np.concatenate([fc.sum(0), np.cross(x - T[:3, 3], fc).sum(0),
                                                       [fp.load_indentation()]]))
        return out

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        """The pads' last solutions (their warm start and friction holds), by pad."""
        return {name: fp.state() for name, fp in self.pads.items()}

    def load_state(self, state) -> None:
        for name, pad_state in state.items():
            self.pads[name].load_state(pad_state)
        self._maps = {}

    def _index(self) -> dict[str, int]:
        return {name: i for i, name in enumerate(self.scene.pads)}

    def flat_state(self) -> dict[str, np.ndarray]:
        """Each pad's last solution as ``fem{i}_*`` (i: the pad's index in the scene's pads;
        :meth:`EquilibriumPad.flat_state`)."""
        out = {}
        index, objects = self._index(), sorted(self.scene.rigid_objects)
        for name in self.names:
            out.update({f"fem{index[name]}_{k}": v for k, v in self.pads[name].flat_state(objects).items()})
        return out

    def load_flat_state(self, state) -> None:
        index, objects = self._index(), sorted(self.scene.rigid_objects)
        for name in self.names:
            prefix = f"fem{index[name]}_"
            if prefix + "force" not in state:
                raise ConfigError(f"load_flat_state: the state has no {prefix}* entries for pad {name!r}, "
                                  "which this scene solves at equilibrium (pad_solver='fem'); a state saved with "
                                  "the MPM pads loads into a scene made "
                                  "with pad_solver='mpm'")
            self.pads[name].load_flat_state({k[len(prefix):]: v for k, v in state.items()
                                             if k.startswith(prefix)}, objects)
        self._maps = {}

    # ------------------------------------------------------------------ rendering
    @property
    def num_particles(self) -> int:
        """The particles of all these pads: the rows of :meth:`frames` (pad after pad, in order)."""
        return sum(self._pad(name).num_particles for name in self.names)

    def rows(self, name: str) -> tuple[int, int]:
        """Pad ``name``'s rows ``start:stop`` among :attr:`num_particles` (pad after pad)."""
        start = 0
        for other in self.names:
            n = self._pad(other).num_particles
            if other == name:
                return start, start + n
            start += n
        raise ConfigError(f"pad {name!r} is not solved at equilibrium; these are: {self.names}")

    def frames(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The frames of the particles ``rows`` ([P'] ascending, of :meth:`rows`' numbering):
        (their positions in ``rows`` [k], their frames (F | x) [k, 3, 4] float32, world frame,
        from :meth:`particles`)."""
        where, frames = [np.zeros(0, np.int64)], [np.zeros((0, 3, 4), np.float32)]
        rows = np.asarray(rows)
        for name in self.names:
            start, stop = self.rows(name)
            lo, hi = np.searchsorted(rows, (start, stop))
            if hi > lo:
                x, F = self.particles(name)
                local = rows[lo:hi] - start
                where.append(np.arange(lo, hi))
                frames.append(np.concatenate([F[local], x[local, :, None]], axis=2))
        return np.concatenate(where), np.concatenate(frames)

    def fill_particles(self, rows: np.ndarray, x: np.ndarray, F: np.ndarray) -> None:
        """``rows``: of :meth:`rows`' numbering (ascending)."""
        where, frames = self.frames(rows)
        x[where], F[where] = frames[:, :, 3], frames[:, :, :3]
