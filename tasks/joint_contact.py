"""The pads' reaction on the hand, folded into the hand's joint drives for one SAPIEN step.

On a fixed-base articulation a link wrench ``w = (f, τ)`` (τ about the link origin) acts as the
joint torque ``τc = Jᵀ w`` (``J`` the link's [6, dof] Jacobian). A PD drive (stiffness ``kp``,
target ``q*``) plus that torque, linearised about the joints' positions ``q₀`` with a contact
stiffness ``D``, is again a PD drive::

    kp (q* - q) + τc - D (q - q₀)  =  (kp + D) (q' - q),   q' = (kp q* + D q₀ + τc) / (kp + D)

so :class:`JointContact` sets each touched joint's drive to ``kp + D`` and ``q'``, and PhysX
integrates the contact implicitly with the drives; at rest the statics are the real drives'
against the pad. ``D_j = K |a_j| Σ_k |a_k|`` (``a = J_cᵀ n``, ``K = GAIN |F| / δ``) bounds
``Σ K aaᵀ`` from above (Gershgorin), so a step only damps the approach to the balance. Not a PhysX
joint on the link: neither PhysX solver converges such a constraint against the articulation's
drives. Only ``"force"``-mode drives fold (an ``"acceleration"`` drive scales by inertia).
"""
import numpy as np

from ..errors import ConfigError
from .contact_spring import GAIN, MIN_DEPTH, centre_of_pressure, frame_along, skew

__all__ = ["JointContact"]

#: least folded drive stiffness [N·m/rad] of a joint a contact torque acts on (a joint with
#: kp = 0 and no contact stiffness still takes τc as ε (q' - q))
_MIN_STIFFNESS = 1.0e-3


class JointContact:
    """One env's hand: folds the pad links' contacts into its joint drives (module docstring).

    Args:
        articulation: the hand's ``sapien.physx.PhysxArticulation`` (fixed root or with its
            base as joints).
        links: the pad links (``PhysxArticulationLinkComponent``), in the order of the
            contact rows passed to :meth:`fold`.

    Raises:
        ConfigError: a joint drive is in ``"acceleration"`` mode.
    """

    def __init__(self, articulation, links):
        self.articulation = articulation
        self.joints = articulation.get_active_joints()
        bad = [j.name for j in self.joints if j.drive_mode != "force"]
        if bad:
            raise ConfigError(f"pad_reaction=True folds the pads' reaction into the hand's joint drives, which "
                              f"must be in 'force' mode; these are not: {bad}")
        self.model = articulation.create_pinocchio_model()
        names = [link.name for link in articulation.get_links()]
        self.links = list(links)
        self.link_index = [names.index(link.name) for link in self.links]
        self._saved: list[tuple] = []  # (joint, stiffness, force_limit, target) changed for this step

    def restore(self) -> None:
        """Give the drives changed by the last :meth:`fold` back their own stiffness,
        force limit and target."""
        for joint, stiffness, force_limit, target in self._saved:
            joint.set_drive_properties(stiffness, joint.damping, force_limit, "force")
            joint.set_drive_target(target)
        self._saved = []

    def jacobian(self, q: np.ndarray, i: int) -> np.ndarray:
        """[6, dof] world-frame Jacobian of pad link ``i`` at joint positions ``q`` (call
        after ``model.compute_full_jacobian(q)``): rows 0-2 the velocity [m/s] of the link
        origin, rows 3-5 its angular velocity [rad/s], per joint velocity."""
        local = self.model.get_link_jacobian(self.link_index[i], local=True)  # in the link frame
        rot = self.links[i].entity_pose.to_transformation_matrix()[:3, :3].astype(np.float64)
        return np.vstack([rot @ local[:3], rot @ local[3:]])

    def fold(self, contacts: np.ndarray, friction=None) -> bool:
        """Set the drives for the coming SAPIEN step from the pad links' contacts of the last
        MPM step (computed at the joints' positions now). A drive keeps its force limit: its
        target is clamped to within ``force_limit / kp`` of ``q₀`` before folding, and the
        folded drive's limit is ``force_limit + |τc|``.

        Args:
            contacts: [links, objects, 7] per pad link and object touched: force [N] and
                torque [N·m] about the link origin (world frame) on the link, indentation [m]
                (:meth:`~gausstac_maniskill.cosim.GaussTacSim.link_contacts`).
            friction: [objects] Coulomb coefficients of the contacts, or ``None`` (0): a
                contact with friction also stiffens the joints that slide the pad across
                the force, with the same ``K`` (a stuck contact resists slip both ways).

        Returns:
            whether any drive was changed.
        """
        self.restore()
        touched = [i for i in range(len(self.links)) if np.any(contacts[i, :, :6])]
        if not touched:
            return False
        q = self.articulation.qpos.astype(np.float64)
        self.model.compute_full_jacobian(q)
        torque = np.zeros_like(q)  # τc = Σ Jᵀ w
        stiffness = np.zeros_like(q)  # D, the diagonal bound of Σ K a aᵀ
        for i in touched:
            J = self.jacobian(q, i)
            for o, row in enumerate(contacts[i]):
                force, moment, depth = row[:3], row[3:6], float(row[6])
                f = float(np.linalg.norm(force))
                if not np.isfinite(f) or not np.all(np.isfinite(moment)):
                    raise FloatingPointError(f"pad contact on {self.links[i].name} is not finite: {row}")
                torque += J[:3].T @ force + J[3:].T @ moment
                if f <= 0.0:
                    continue
                n = force / f
                arm = centre_of_pressure(force, moment, np.zeros(3))  # from the link origin
                Jc = J[:3] - skew(arm) @ J[3:]  # velocity of that point, per joint velocity
                k = GAIN * f / max(depth, MIN_DEPTH)
                stuck = friction is not None and friction[o] > 0.0
                for d in (frame_along(n).T if stuck else n[None]):  # along n (and across it, if stuck)
                    a = Jc.T @ d
                    stiffness += k * np.abs(a) * np.abs(a).sum()
        for j in np.flatnonzero((torque != 0.0) | (stiffness > 0.0)):
            joint = self.joints[j]
            kp, limit, target = float(joint.stiffness), float(joint.force_limit), float(joint.drive_target[0])
            self._saved.append((joint, kp, limit, target))
            if kp > 0.0:  # the drive's own torque stays within its force limit
                target = q[j] + np.clip(target - q[j], -limit / kp, limit / kp)
            k = max(kp + stiffness[j], _MIN_STIFFNESS)
            joint.set_drive_properties(k, joint.damping, limit + abs(torque[j]), "force")
            joint.set_drive_target((kp * target + (k - kp) * q[j] + torque[j]) / k)
        return True

