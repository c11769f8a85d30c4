"""What an MPM world reads back (:class:`WorldReadouts`, part of
:class:`~gausstac_maniskill.mpm.solver.MPMWorld`): particle positions, velocities, deformation and
stress, contact forces per particle, wrenches and contacts per collider and link, energies, and
the link poses and twists of the last step."""
from __future__ import annotations

import numpy as np
import taichi as ti

from ..errors import ConfigError
from ..transforms import quat_to_matrix
from . import kernels as K
from .state import PARTICLE_FIELDS


class WorldReadouts:
    """Read-back of an :class:`~gausstac_maniskill.mpm.solver.MPMWorld` (a part of it: the state
    it reads is the world's)."""

    def _read(self, key: str, group: str | None):
        self._pull((key,))  # only the field read comes back from the device
        arr = self._host_parts.get(key)
        if arr is None:  # a world without particles
            f = PARTICLE_FIELDS[key]
            return np.zeros((0, *f.row), np.int32 if f.dtype == ti.i32 else np.float32)
        if group is None:
            return arr.copy()
        g = self.group(group)
        return arr[g.start:g.stop].copy()

    def positions(self, group: str | None = None) -> np.ndarray:
        """Particle positions [N, 3] in metres (all groups, or one)."""
        return self._read("x", group)

    def velocities(self, group: str | None = None) -> np.ndarray:
        """Particle velocities [N, 3] in m/s."""
        return self._read("v", group)

    def deformation_gradients(self, group: str | None = None) -> np.ndarray:
        """Deformation gradients F [N, 3, 3] relative to the rest configuration."""
        return self._read("F", group)

    def stresses(self, group: str | None = None) -> np.ndarray:
        """Cauchy stress σ = τ / J [N, 3, 3] in pascals."""
        tau = self._read("tau", group)
        J = np.linalg.det(self._read("F", group))
        return tau / np.maximum(J, 1e-6)[:, None, None]

    def device_state(self, keys=("x", "v", "F", "tau")) -> dict:
        """The particle state arrays ``keys`` where the kernels keep them (Taichi ndarrays on
        the arch's device, all groups, [N, ...] rows), up to date with every change made on
        the host: for kernels that read the state without copying it back
        (:class:`~gausstac_maniskill.tactile.readout.TactileReadout`). Do not write them."""
        self._push()
        arrays = {k: self._dev_parts.get(k) if k in PARTICLE_FIELDS else getattr(self._dev, k, None) for k in keys}
        missing = [k for k, a in arrays.items() if a is None]
        if missing:
            raise ConfigError(f"device_state: the world has no particles (no device array {missing[0]!r})")
        return arrays

    def rest_positions(self, group: str | None = None) -> np.ndarray:
        """Kinematic particles' rest coordinates [N, 3] in their link frame (0 for others)."""
        return self._read("X0", group)

    def rest_volumes(self, group: str | None = None) -> np.ndarray:
        """Rest volume V0 [m³] of each particle, [N]."""
        return self._read("vol", group)

    def virtual_work_force(self, group: str, grad_phi) -> np.ndarray:
        """Force [N, world frame] that a group's boundary loads exert where a test field φ is 1,
        read from its stress: ∫ σ ∇φ dV = ∫ φ t dA (weak form of equilibrium, exact in
        equilibrium when φ vanishes wherever else the group is loaded, e.g. at its bond).

        Args:
            group: group name.
            grad_phi: [N, 3] ∇φ of each particle [1/m] in the rest configuration (world frame
                at binding, see :meth:`binding_rotation`); zero rows drop a particle.
        Returns:
            [3] Σ_p V0_p J_p σ_p F_p⁻ᵀ ∇φ_p = Σ_p V0_p τ_p F_p⁻ᵀ ∇φ_p (τ Kirchhoff).
        """
        g = np.asarray(grad_phi, np.float64)
        n = self.group(group).count
        if g.shape != (n, 3):
            raise ConfigError(f"virtual_work_force({group!r}): grad_phi must have shape {(n, 3)}, got {g.shape}")
        use = np.any(g != 0.0, axis=1)
        F = self.deformation_gradients(group)[use].astype(np.float64)
        tau = self._read("tau", group)[use].astype(np.float64)
        grad_x = np.linalg.solve(np.transpose(F, (0, 2, 1)), g[use][..., None])[..., 0]
        return np.einsum("n,nij,nj->i", self.rest_volumes(group)[use], tau, grad_x)

    def binding_rotation(self, group: str) -> np.ndarray:
        """World rotation (3x3) of a group's link when the group was added: the frame its
        deformation gradients are measured from (identity for a group without a link)."""
        self._pull()
        self.group(group)  # clear error if unknown
        return quat_to_matrix(self.model.group_bind[self.model.group_index(group)].astype(np.float64))

    def kinematic_mask(self, group: str | None = None) -> np.ndarray:
        """[N] bool: which particles are kinematic."""
        return self._read("kind", group).astype(bool)

    def contact_forces(self, group: str | None = None) -> np.ndarray:
        """Mean contact force [N, 3] (newtons) each particle received from colliders
        during the last control step (impulse / Δt_ctrl); zero where no contact."""
        return self._read("impulse", group) / self._last_dt_ctrl

    def contact_collider(self, group: str | None = None) -> np.ndarray:
        """[N] index of the collider each particle last touched (-1: none)."""
        return self._read("contact_id", group)

    def collider_wrench(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Mean reaction (force [N], torque [N·m] about the collider origin) that
        collider ``index`` received from the particles during the last control step."""
        self._collider(index)
        J = self._col_impulse[index] / self._last_dt_ctrl if len(self._col_impulse) else np.zeros(6)
        return J[:3].copy(), J[3:].copy()

    def link_wrench(self, link) -> tuple[np.ndarray, np.ndarray]:
        """Mean reaction (force [N], torque [N·m] about the link's origin, world frame) that
        ``link`` (name or index) received through the particles bound to it during the last
        control step: the contact impulses those particles took from colliders and from the
        other field, passed on by a massless layer (see :func:`kernels.reduce_contact`).
        Equal and opposite to the colliders' share of :meth:`collider_wrench`."""
        J = self._pair_impulse[self.link_index(link), :, :6].sum(0) / self._last_dt_ctrl
        return J[:3].copy(), J[3:].copy()

    def link_contacts(self, link) -> np.ndarray:
        """[len(colliders) + 1, 7] per object that ``link``'s particles touched during the last
        control step: the mean force [N] and torque [N·m] (about the link's origin, world
        frame) it passed to the link, and the indentation [m] (the deepest displacement of
        a touching particle from its rest place on the link, along its push). Row c < C:
        collider c; the last row: the other velocity field (soft objects). Rows sum to
        :meth:`link_wrench`."""
        out = self._pairs(np.array([self.link_index(link)]), np.arange(len(self.colliders)))[0]
        out[:, :6] /= self._last_dt_ctrl
        return out

    def energy(self) -> tuple[float, float]:
        """(kinetic, elastic) energy [J] of the awake dynamic particles; the kinetic energy is
        APIC's, with the affine velocity's share (:func:`kernels.energies`)."""
        self._push()
        out = ti.ndarray(ti.f32, shape=2)
        active = self._dev.active
        K.energies(self._pack["P"], active, self._n_active, self._dev.mat_table, self.settings.dx, out)
        e = out.to_numpy()
        return float(e[0]), float(e[1])

    def link_pose(self, link) -> np.ndarray:
        """World pose (4x4) of a link at the end of the last step: where its particles are."""
        return self._link_prev[self.link_index(link)].copy()

    def link_poses(self) -> np.ndarray:
        """[L, 4, 4] world poses [m] of every link (in :attr:`link_names` order) at the end of
        the last step."""
        return self._link_prev.copy()

    def link_twist(self, link) -> tuple[np.ndarray, np.ndarray]:
        """(velocity of the link origin [m/s], angular velocity [rad/s]) over the last step."""
        w = self._link_twist[self.link_index(link)]
        return w[:3].copy(), w[3:].copy()

    @property
    def last_dt_ctrl(self) -> float:
        """Length [s] of the last control step."""
        return self._last_dt_ctrl

    def collider_start_pose(self, index: int) -> np.ndarray:
        """World pose (4x4) of collider ``index`` at the end of the last step, where the next
        step moves it from (its target is ``colliders[index].pose``)."""
        self._collider(index)
        return self._col_prev[index].copy()
