"""The pads' reaction on a two-way object as a spring that PhysX integrates implicitly.

A pad pressed on a free object pushes it with the force F(x) of the MPM layer. Applied as an
external force, one SAPIEN step late, that is an explicit spring: with a light object
(10-50 g) and a crushed pad's contact stiffness (1e4-1e5 N/m) it is stable only for SAPIEN
steps below about 2 sqrt(m/k).

:class:`ObjectSpring` hands the pads' forces on one object to PhysX as one implicit spring
instead: a D6 joint from the world to the object's centre of mass, with linear drives along
three axes and angular drives about them, which PhysX's solver integrates with the object's
motion like a joint drive:

* at the pose the MPM forces were computed at, the spring pushes with exactly the pads'
  summed force and moment (each pad's force through its centre of pressure, plus its twist
  couple about its force);
* when the object moves during the SAPIEN step, the push changes by the contacts' stiffness:
  ``K = OBJECT_GAIN |F| / δ`` per contact (δ the pad's indentation; the secant stiffness of
  the contact times :data:`OBJECT_GAIN`) along the contact's force, as much across it when
  the contact has friction (a stuck contact resists slip within the step, up to what
  ``μ |F|`` can carry), ``K r²`` about it (r = :data:`TWIST_RADIUS`); summed over the
  contacts and bounded from above per axis (Gershgorin, as :mod:`.joint_contact` does);
* the axes are the principal directions of the pads' normal forces, x along the strongest
  push: when every pad pushes along +x, x is a one-sided limit that never pulls; when pads
  push from both sides (a pinch) it is a drive, which keeps every pad compressed as long as
  the object moves less than the pads' gaps;
* the spring's target moves with the pads (the stiffness-weighted velocity of the contact
  points on their links), so the object follows the fingers within the step (a spring fixed
  in the world held the cube back while the hand lifted it).

Why one joint per object, not one per pad: PhysX's PGS solver settles two soft constraints
acting along the same direction of one body at a wrong balance. A 10 g box between two
one-sided D6 soft limits preloaded with the held cube's pad forces (0.115 N at 9.2e3 N/m and
1.897 N at 2.7e4 N/m, 100 Hz) moves +4.08 µm in one step where their implicit Euler step is
-49.60 µm (each limit alone is exact: +12.36 and -70.98 µm; at three times the stiffness,
+2.66 µm for -16.5, and -3.8 µm with 100 solver iterations instead of 15). One soft row per
direction is exact: the joint of this class moves it -49.60 µm. With one spring per pad a
pinched 10 g cube hung still while its pads' MPM forces differed by 1.8 N (0.115 and
1.897 N at dx = 2 mm); with one spring per object they add up to the cube's weight within
0.3 % (``python -m gausstac_maniskill.bench hold``).

Each SAPIEN step the MPM recomputes F at the new pose, so the spring only has to predict how
F changes within one step. For a power-law contact F ∝ δ^p the tangent stiffness is
``p |F| / δ``, and the quasi-static iteration ``δ ← δ + (F_drive - F(δ)) / K`` converges when
``K`` exceeds half of it: ``GAIN = 3`` covers 1 <= p < 6 (flat and Hertzian contacts, thin
bonded layers), and a stiffer spring than the contact only makes the settling slower
(never faster than the MPM's own response).

On a free rigid body PhysX's PGS solver holds such a spring to 1e-4 (a 10 g body pushed by
10 N against a 1e4 N/m spring settles 1.0000 mm deep), its TGS solver does not (0.33 mm at
ManiSkill's 15 position iterations, on the wrong side at 4); hence
``GaussTacEnv(pad_reaction=True)`` runs SAPIEN with ``enable_tgs=False``. The hand's side of
the contact is not a spring but folded into its joint drives (:mod:`.joint_contact`): a
PhysX joint on an articulation link does not converge against the link's drives.
"""
from dataclasses import dataclass

import numpy as np
import sapien

from ..transforms import matrix_to_quat

__all__ = ["ObjectSpring", "GAIN", "OBJECT_GAIN", "MIN_DEPTH", "TWIST_RADIUS", "centre_of_pressure", "frame_along",
           "skew"]

#: spring stiffness over the contact's secant stiffness |F|/δ (see the module docstring)
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
    that bound the contacts' summed stiffness from above (row sums of its absolute values,
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
