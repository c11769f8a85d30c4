"""The pads' reaction on a two-way object as a spring that PhysX integrates implicitly.

A pad pressed on a free object pushes it with the force F(x) of the MPM layer. Applied as an
external force, one SAPIEN step late, that is an explicit spring: with a light object
(10-50 g) and a crushed pad's contact stiffness (1e4-1e5 N/m) it is stable only for SAPIEN
steps below about 2 sqrt(m/k).

:class:`ContactSpring` hands the same force to PhysX as a one-sided spring instead: a D6
joint from the pad's link to the object (the link takes none of it), limited along the
force's line of action with a soft limit that PhysX's solver treats implicitly, like a
joint drive:

* at the pose the MPM force was computed at, the spring pushes with exactly ``|F|`` along
  ``n = F/|F|``, through the centre of pressure;
* when the object moves by ``s`` along ``-n`` during the SAPIEN step (further into the pad),
  the force grows by ``K s`` within that same step, with ``K = OBJECT_GAIN |F| / δ`` (δ the
  pad's indentation): the secant stiffness of the contact times :data:`OBJECT_GAIN`;
* it never pulls: past the limit the joint is free;
* across ``n``, a stuck contact resists slip within the step: a drive of the same stiffness
  ``K`` holds the object where F was computed relative to the pad's link, up to ``μ |F|``
  (friction's response, which an explicit force would give one step late: a 50 g cube
  pinched by two pads and lifted at 100 Hz chattered and slid out, 2-5 cm/s, without it).
  Measured, not as designed: on a light object pinched by two pads (10 g, K dt²/m of
  300-800) these drives also block its motion along the pinch axis, even with their caps at
  0.1 % of ``μ |F|``, so the object stays where it is although the pads' MPM forces do not
  balance (``python -m gausstac_maniskill.bench hold``; cause not found);
* about ``n``, the pad's twist couple is preloaded in a twist spring of stiffness ``K r²``
  (explicit, a 50 g cube pinched between two pads rocked about the pinch axis at ±8 mm/s,
  flipping every SAPIEN step);
* the spring rides on the pad's link, so the object follows the finger's motion within the
  step (a world-anchored spring held the cube back while the hand lifted it).

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
import numpy as np
import sapien

from ..transforms import matrix_to_quat

__all__ = ["ContactSpring", "GAIN", "OBJECT_GAIN", "MIN_DEPTH", "TWIST_RADIUS", "centre_of_pressure", "frame_along"]

#: spring stiffness over the contact's secant stiffness |F|/δ (see the module docstring)
GAIN = 3.0
#: the object springs' stiffness over the contact's secant stiffness: a light object held
#: between two pads needs more than GAIN (a 10 g cube pinched by the thumb and index pads at
#: dx = 2 mm, 100 Hz: GAIN 3 chattered at ±11 mm/s, flipping every SAPIEN step; 12 settled
#: first, then grew back to 1.0 mm/s; 24 settles under 0.05 mm/s; a stiffer spring only
#: slows the settling)
OBJECT_GAIN = 24.0
#: smallest indentation [m] used for the stiffness (a graze with no measured depth)
MIN_DEPTH = 1.0e-5
#: radius [m] of a pad's contact patch for the twist spring (stiffness K r², friction μ|F| r):
#: about the half width of a fingertip's contact; larger only stiffens the twist
TWIST_RADIUS = 1.0e-2


class ContactSpring:
    """One pad link's contact with one two-way object, as a one-sided spring along the MPM
    force's line of action that PhysX integrates with the object's motion.

    The spring rides on the pad's link and moves the object only (PhysX sees the link as
    infinitely heavy for it: inverse mass and inertia scale 0), so the object follows the
    finger within the step, while the link's side of the contact goes through its drives
    (:mod:`.joint_contact`).

    Args:
        sub_scene: the SAPIEN scene of one env.
        body: the object's entity.
        link: the pad link's entity.
    """

    def __init__(self, sub_scene, body, link):
        self.body, self.link = body, link
        self.drive = sub_scene.create_drive(link, sapien.Pose(), body, sapien.Pose())
        self.drive.set_inv_mass_scales(0.0, 1.0)
        self.drive.set_inv_inertia_scales(0.0, 1.0)
        self._free = self.drive.get_limit_x()  # unlimited, as created
        self.active = False

    def take(self, contact: np.ndarray, friction: float) -> np.ndarray:
        """Set the spring from the link's side of a contact of the last MPM step and return
        the wrench it now carries on the object.

        Args:
            contact: [7] force [N] and torque [N·m] about the link origin (world frame) that
                the object passed to the link, and the pad's indentation [m] (a row of
                :meth:`~gausstac_maniskill.cosim.GaussTacSim.link_contacts`).
            friction: the contact's Coulomb coefficient (see :meth:`update`).

        Returns:
            [6] force [N] and torque [N·m] about the object's origin (world frame) on the
            object that the spring applies; zero when it is released.
        """
        if not np.any(contact[:3]):
            self.release()
            return np.zeros(6)
        force = -contact[:3]  # on the object
        origin = np.asarray(self.link.pose.p, np.float64)
        point = centre_of_pressure(contact[:3], contact[3:6], origin)
        n = force / np.linalg.norm(force)
        # the couple left about the line of action (the pad's twist), on the object
        twist = -float((contact[3:6] - np.cross(point - origin, contact[:3])) @ n)
        if not self.update(force, point, contact[6], friction, twist):
            return np.zeros(6)
        arm = point - np.asarray(self.body.pose.p, np.float64)
        return np.concatenate([force, np.cross(arm, force) + twist * n])

    def release(self) -> None:
        """No force until the next :meth:`update` with contact."""
        if self.active:
            self.drive.set_limit_x(*self._free)
            for axis in (self.drive.set_drive_property_y, self.drive.set_drive_property_z,
                         self.drive.set_drive_property_twist):
                axis(0.0, 0.0)
            self.active = False

    def update(self, force: np.ndarray, point: np.ndarray, depth: float, friction: float = 0.0,
               twist: float = 0.0) -> bool:
        """Set the spring for the coming SAPIEN step from a contact of the last MPM step,
        computed at the object's pose now.

        Args:
            force: [3] force [N] the pad exerted on the object (world frame).
            point: [3] a world point [m] on its line of action.
            depth: the pad's indentation [m].
            friction: the contact's Coulomb coefficient μ: across the line of action the
                object is held where it is by a spring of the same stiffness, up to
                ``μ |F|`` (a stuck contact resists slip within the step; 0: free).
            twist: the pad's couple [N·m] on the object about ``n`` (the moment left about
                the line of action): applied by a twist spring of stiffness ``K r²``
                (r = :data:`TWIST_RADIUS`), which also resists the object's turning about
                ``n`` within the step, up to ``|twist| + μ |F| r``.

        Returns:
            whether the spring acts (``False``: no force, spring released).
        """
        f = float(np.linalg.norm(force))
        if f <= 0.0 or not np.isfinite(f):
            self.release()
            return False
        stiffness = OBJECT_GAIN * f / max(float(depth), MIN_DEPTH)
        frame = sapien.Pose(np.asarray(point, np.float32), matrix_to_quat(frame_along(force / f)).astype(np.float32))
        self.drive.set_pose_in_child(self.body.pose.inv() * frame)
        self.drive.set_pose_in_parent(self.link.pose.inv() * frame)
        # x: the body's offset along n from where F was computed; pushed while x < f / K
        self.drive.set_limit_x(f / stiffness, float(self._free[1]), stiffness, 0.0)
        cap = float(friction) * f
        for axis in (self.drive.set_drive_property_y, self.drive.set_drive_property_z):
            axis(stiffness if cap > 0.0 else 0.0, 0.0, max(cap, 0.0), "force")
        k_twist = stiffness * TWIST_RADIUS ** 2
        self.drive.set_drive_property_twist(k_twist, 0.0, abs(float(twist)) + cap * TWIST_RADIUS, "force")
        # across n: held at the pose F was computed at; about n: turned by the twist's preload angle
        angle = float(twist) / k_twist
        self.drive.set_drive_target(sapien.Pose(q=[np.cos(angle / 2), np.sin(angle / 2), 0.0, 0.0]))
        self.active = True
        return True


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
