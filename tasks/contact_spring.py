"""The pads' reaction on a two-way object as one spring that PhysX integrates implicitly.

The pads push a free object with the force F(x) of the pad solver. Applied as an external force
one SAPIEN step late, that is an explicit spring, stable only for steps below about 2 sqrt(m/k)
(objects of 10-50 g, contact stiffness k of 1e4-1e5 N/m). :class:`ObjectSpring` hands it to PhysX
as one D6 joint from the world to the object's centre of mass: at the pose F was computed at, its
drives push exactly the pads' summed force [N] and moment [N·m]; as the object moves within the
step the push changes by ``K = OBJECT_GAIN |F| / δ`` [N/m] per contact (δ the pad's indentation
[m]; :data:`GAIN` says why a multiple of the secant stiffness converges).

One joint per object, not one per pad: PhysX's PGS solver settles two soft constraints along one
direction of one body at a wrong balance; one soft row per direction is exact. Its TGS solver does
not hold such a spring on a free body, hence ``GaussTacEnv(pad_reaction=True)`` runs SAPIEN with
``enable_tgs=False``. The hand's side is folded into its joint drives instead (:mod:`.joint_contact`):
a PhysX joint on an articulation link does not converge against the link's drives.
"""
from dataclasses import dataclass

import numpy as np
import sapien

from ..transforms import matrix_to_quat

__all__ = ["ObjectSpring", "GAIN", "OBJECT_GAIN", "MIN_DEPTH", "TWIST_RADIUS", "centre_of_pressure", "frame_along",
           "skew"]

#: spring stiffness over the contact's secant stiffness |F|/δ: for F ∝ δ^p the tangent stiffness is
#: p |F|/δ, and the quasi-static iteration δ ← δ + (F_drive - F(δ)) / K converges when K exceeds half
#: of it, so 3 covers 1 <= p < 6 (flat and Hertzian contacts, thin bonded layers); a stiffer spring
#: only slows the settling
GAIN = 3.0
#: the object spring's stiffness over each contact's secant stiffness: a light object held
#: between two pads needs more than GAIN (a 10 g cube pinched by the thumb and index pads at
#: dx = 2 mm, 100 Hz: 3 flips the pads' forces between 0.5 and 1.5 N every step, the cube at
#: 7.7 mm/s; 8 settles in 0.3 s to 0.001 mm/s with the pads balanced; 24 settles too, in
#: over 2 s: a stiffer spring only slows the settling)
OBJECT_GAIN = 8.0
#: smallest indentation [m] used for the stiffness (a graze with no measured depth)
MIN_DEPTH = 1.0e-5
#: pads push the object from both sides along the spring's x axis when the weaker side pushes
#: more than this fraction of the stronger (a pinch); below, the weaker is a graze and x a
#: one-sided limit that never pulls
OPPOSED = 0.1
#: a drive force limit that never binds [N]
_NO_CAP = 1.0e30
#: radius [m] of a pad's contact patch for the twist spring (stiffness K r², friction μ|F| r):
#: about the half width of a fingertip's contact; larger only stiffens the twist
TWIST_RADIUS = 1.0e-2


class ObjectSpring:
    """All pads' contacts with one two-way object of one env, as one spring that PhysX
    integrates implicitly with the object's motion (module docstring).

    One D6 joint from the world to the object's centre of mass carries the pads' summed
    wrench: linear drives (or a one-sided limit) along three axes and twist/swing drives
    about them, each preloaded so that it pushes exactly the MPM's wrench at the pose it was
    computed at, with the contacts' summed stiffness for the motion within the step. Its
    axes are the principal directions of the pads' normal forces, x along the strongest push:
    a one-sided limit that never pulls when every pad pushes along +x, a drive in a pinch. Its
    target moves with the pads (their links' velocity at the contacts), so the object
    follows the fingers within the step.

    Args:
        sub_scene: the SAPIEN scene of one env.
        body: the object's entity (a free rigid body).
    """

    def __init__(self, sub_scene, body):
        self.body = body
        self.rigid = body.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)
        self.drive = sub_scene.create_drive(None, sapien.Pose(), body, sapien.Pose())
        self._free = self.drive.get_limit_x()  # unlimited, as created
        self.active = False

    def release(self) -> None:
        """No force until the next :meth:`take` with contact."""
        if self.active:
            self.drive.set_limit_x(*self._free)
            for axis in (self.drive.set_drive_property_x, self.drive.set_drive_property_y,
                         self.drive.set_drive_property_z, self.drive.set_drive_property_twist,
                         self.drive.set_drive_property_swing):
                axis(0.0, 0.0, 0.0, "force")
            self.active = False

    def take(self, contacts: list, friction: float) -> np.ndarray:
        """Set the spring for the coming SAPIEN step from the pads' contacts of the last MPM
        step with this object (computed at its pose now) and return the wrench it carries.

        Args:
            contacts: ``(row, link)`` per pad link: ``row`` [7] the force [N] and torque
                [N·m] about the link origin (world frame) the object passed to the link and
                the pad's indentation [m] (a row of
                :meth:`~gausstac_maniskill.cosim.GaussTacSim.link_contacts`); ``link`` the
                link's rigid body (``PhysxArticulationLinkComponent``: its pose and
                velocity). Rows without force are skipped.
            friction: the contacts' Coulomb coefficient μ: with μ > 0 a contact is taken as
                stuck within the step (as stiff across its force as along it), and the
                drives across the contacts' forces stop at what friction can carry.

        Returns:
            [6] force [N] and torque [N·m] about the object's origin (world frame) that the
            spring applies to the object; zero when released.
        """
        parts = [_contact_part(row, link, friction) for row, link in contacts if np.any(row[:3])]
        parts = [c for c in parts if c is not None]
        if not parts:
            self.release()
            return np.zeros(6)
        com = np.asarray((self.body.pose * self.rigid.cmass_local_pose).p, np.float64)
        force = sum(c.force for c in parts)
        torque = sum(np.cross(c.point - com, c.force) + c.couple for c in parts)  # about the centre of mass
        # the joint's axes: principal directions of the normal forces, x along the strongest push
        normals = sum(np.linalg.norm(c.force) * np.outer(c.n, c.n) for c in parts)
        R = np.linalg.eigh(normals)[1][:, ::-1].copy()
        if force @ R[:, 0] < 0.0:
            R[:, 0] = -R[:, 0]
        if np.linalg.det(R) < 0.0:
            R[:, 2] = -R[:, 2]
        k_lin, k_ang, cap_lin, cap_ang = _stiffness(parts, com, R, friction)
        # where the pads move in the step (stiffness-weighted velocity of the contact points)
        weight = np.array([c.k for c in parts])
        v_pad = sum(w * c.velocity for w, c in zip(weight, parts)) / weight.sum()
        w_pad = sum(w * c.spin for w, c in zip(weight, parts)) / weight.sum()
        dt = float(self.body.scene.physx_system.timestep)
        f_local, t_local = R.T @ force, R.T @ torque
        carried_f = np.where(k_lin > 0.0, f_local, 0.0)
        carried_t = np.where(k_ang > 0.0, t_local, 0.0)
        frame = sapien.Pose(com.astype(np.float32), matrix_to_quat(R).astype(np.float32))
        self.drive.set_pose_in_child(self.body.pose.inv() * frame)
        self.drive.set_pose_in_parent(frame)
        offset = np.divide(carried_f, k_lin, out=np.zeros(3), where=k_lin > 0.0) + R.T @ v_pad * dt
        angle = np.divide(carried_t, k_ang, out=np.zeros(3), where=k_ang > 0.0) + R.T @ w_pad * dt
        push = [float(c.force @ R[:, 0]) for c in parts]
        if min(push) < -OPPOSED * max(push):  # pads push from both sides along x (a pinch): a two-sided spring
            self.drive.set_limit_x(*self._free)
            self.drive.set_drive_property_x(k_lin[0], 0.0, cap_lin[0], "force")
        else:  # pushed along +x only: never pulls
            self.drive.set_drive_property_x(0.0, 0.0, 0.0, "force")
            self.drive.set_limit_x(float(offset[0]), float(self._free[1]), float(k_lin[0]), 0.0)
        self.drive.set_drive_property_y(k_lin[1], 0.0, cap_lin[1], "force")
        self.drive.set_drive_property_z(k_lin[2], 0.0, cap_lin[2], "force")
        self.drive.set_drive_property_twist(k_ang[0], 0.0, cap_ang[0], "force")
        self.drive.set_drive_property_swing(k_ang[1], 0.0, cap_ang[1], "force")  # k_ang[1] == k_ang[2]
        self.drive.set_drive_target(sapien.Pose(offset.astype(np.float32), _rotation_quat(angle)))
        self.active = True
        torque_origin = R @ carried_t + np.cross(com - np.asarray(self.body.pose.p, np.float64), R @ carried_f)
        return np.concatenate([R @ carried_f, torque_origin])


@dataclass
class _Contact:
    """One pad link's contact as the object feels it (world frame, SI)."""

    force: np.ndarray  # [3] on the object
    point: np.ndarray  # [3] on its line of action (the centre of pressure)
    n: np.ndarray  # [3] its direction
    couple: np.ndarray  # [3] the pad's twist about n, on the object
    k: float  # stiffness along n (and across it when stuck)
    velocity: np.ndarray  # [3] of the link's material point at ``point``
    spin: np.ndarray  # [3] the link's angular velocity


def _contact_part(row: np.ndarray, link, friction: float):
    """A :class:`_Contact` from a link's contact row (see :meth:`ObjectSpring.take`)."""
    f = float(np.linalg.norm(row[:3]))
    if not np.isfinite(f) or not np.all(np.isfinite(row[3:6])) or f <= 0.0:
        return None
    force = -row[:3]  # on the object
    origin = np.asarray(link.entity_pose.p, np.float64)
    point = centre_of_pressure(row[:3], row[3:6], origin)
    n = force / f
    couple = -float((row[3:6] - np.cross(point - origin, row[:3])) @ n) * n  # the pad's twist, on the object
    k = OBJECT_GAIN * f / max(float(row[6]), MIN_DEPTH)
    omega = np.asarray(link.angular_velocity, np.float64)
    velocity = np.asarray(link.linear_velocity, np.float64) + np.cross(omega, point - origin)
    return _Contact(force, point, n, couple, k, velocity, omega)


def _stiffness(parts: list, com: np.ndarray, R: np.ndarray, friction: float):
    """Per axis of the joint frame ``R``: the linear and angular stiffness [N/m, N·m/rad]
    (per contact ``K`` along its force, also across it with friction, ``K r²`` about it with
    r = :data:`TWIST_RADIUS`) that bound the contacts' summed stiffness from above (row sums of its absolute values,
    Gershgorin, like :mod:`.joint_contact`), and the force [N] and torque [N·m] the drives may
    reach (what the contacts' forces and their friction can carry)."""
    S_lin, S_ang = np.zeros((3, 3)), np.zeros((3, 3))
    cap_lin, cap_ang = np.zeros(3), np.zeros(3)
    stuck = friction > 0.0
    for c in parts:
        P = np.eye(3) if stuck else np.outer(c.n, c.n)  # directions the contact resists
        r = c.point - com
        X = skew(r)
        S_lin += c.k * P
        S_ang += c.k * (X @ P @ X.T) + c.k * TWIST_RADIUS ** 2 * np.outer(c.n, c.n)
        f = float(np.linalg.norm(c.force))
        cap_lin += np.abs(R.T @ c.force) + friction * f
        cap_ang += np.abs(R.T @ (np.cross(r, c.force) + c.couple)) + friction * f * (np.linalg.norm(r) + TWIST_RADIUS)
    k_lin = np.abs(R.T @ S_lin @ R).sum(axis=1)
    k_ang = np.abs(R.T @ S_ang @ R).sum(axis=1)
    # PhysX's swing drive has one stiffness and one limit for both swing axes: the larger
    k_ang[1:], cap_ang[1:] = k_ang[1:].max(), cap_ang[1:].max()
    cap_lin[0] = _NO_CAP  # x: along the pads' pushes, which grow as the object moves in
    return k_lin, k_ang, cap_lin, cap_ang


def _rotation_quat(angle: np.ndarray) -> np.ndarray:
    """wxyz quaternion of the rotation vector ``angle`` [rad]."""
    a = float(np.linalg.norm(angle))
    if a < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0], np.float32)
    return np.concatenate([[np.cos(a / 2)], np.sin(a / 2) * angle / a]).astype(np.float32)


def skew(v: np.ndarray) -> np.ndarray:
    """The matrix of ``v ×``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def centre_of_pressure(force: np.ndarray, moment: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """The point of a force's line of action nearest ``origin`` [m], from the force [N] and
    its moment about ``origin`` [N·m] (world frame)."""
    return origin + np.cross(force, moment) / float(force @ force)


def frame_along(n: np.ndarray) -> np.ndarray:
    """A rotation matrix whose x axis is the unit vector ``n``."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    y = np.cross(helper, n)
    y /= np.linalg.norm(y)
    return np.stack([n, y, np.cross(n, y)], axis=1)
