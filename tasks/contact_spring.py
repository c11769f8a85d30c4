"""The pad's reaction on its link as a spring that PhysX integrates implicitly.

A pad pressed on an object pushes its link back with the force F(x) of the MPM layer. Applied
as an external force, one SAPIEN step late, that is an explicit spring: with the hand's
light distal links (10-40 g) and a crushed pad's contact stiffness (1e4-1e5 N/m) it is stable
only for SAPIEN steps below about 2 sqrt(m/k) (measured: a finger closed hard on a cube is
flung at 100-1000 Hz, holds at 2000 Hz).

:class:`ContactSpring` hands the same force to PhysX as a one-sided spring instead: a D6
joint between the link and the object (or the world), limited along the force's line of
action with a soft limit that PhysX's solver treats implicitly, like its joint drives:

* at the pose the MPM force was computed at, the spring pushes with exactly the MPM force
  ``|F|`` along ``n = F/|F|``, through the centre of pressure ``c`` (the point of F's line of
  action nearest the link origin);
* when the link moves by ``s`` along ``-n`` during the SAPIEN step (further into the object),
  the force grows by ``K s`` within that same step, with ``K = GAIN |F| / δ`` (δ the pad's
  indentation): the secant stiffness of the contact times :data:`GAIN`;
* it never pulls: past the limit the joint is free.

Each SAPIEN step the MPM recomputes F at the new pose, so the spring only has to predict how
F changes within one step. For a power-law contact F ∝ δ^p the tangent stiffness is
``p |F| / δ``, and the quasi-static iteration ``δ ← δ + (F_drive - F(δ)) / K`` converges when
``K`` exceeds half of it: ``GAIN = 3`` covers 1 <= p < 6 (flat and Hertzian contacts, thin
bonded layers), and a stiffer spring than the contact only makes the settling slower
(never faster than the MPM's own response).

PhysX's TGS solver does not hold a joint spring's stiffness against other forces (a 10 g
body pushed by 10 N against a 1e4 N/m spring settles 0.33 mm deep instead of 1 mm at 15
position iterations, and on the wrong side at 4), PGS does to 1e-4; hence
``GaussTacEnv(pad_reaction=True)`` runs SAPIEN with ``enable_tgs=False``.
"""
import numpy as np
import sapien

from ..transforms import matrix_to_quat

__all__ = ["ContactSpring", "GAIN", "MIN_DEPTH"]

#: spring stiffness over the contact's secant stiffness |F|/δ (see the module docstring)
GAIN = 3.0
#: smallest indentation [m] used for the stiffness (a graze with no measured depth)
MIN_DEPTH = 1.0e-5


class ContactSpring:
    """One pad link's contact with one object (or with the world), as a one-sided spring
    along the MPM force's line of action that PhysX integrates with the link's motion.

    Args:
        sub_scene: the SAPIEN scene of one env.
        link: the pad link's entity.
        parent: the object's entity that takes the spring's reaction (a two-way coupled
            object), or ``None`` to hold the spring in the world frame.
    """

    def __init__(self, sub_scene, link, parent=None):
        self.link, self.parent = link, parent
        self.drive = sub_scene.create_drive(parent, sapien.Pose(), link, sapien.Pose())
        self._free = self.drive.get_limit_x()  # unlimited, as created
        self.active = False

    def release(self) -> None:
        """No force until the next :meth:`update` with contact."""
        if self.active:
            self.drive.set_limit_x(*self._free)
            self.active = False

    def update(self, contact: np.ndarray):
        """Set the spring for the coming SAPIEN step from the link's contact of the last MPM
        step, computed at the link's pose now.

        Args:
            contact: [7] force [N] and torque [N·m] about the link origin (world frame) that
                the pad passed to the link, and its indentation [m]
                (:meth:`~gausstac_maniskill.cosim.GaussTacSim.link_contacts`).

        Returns:
            ``(force [3] N, point [3] m)``: the force the spring exerts on the link now and
            the world point it acts at, or ``None`` without contact (spring released).
        """
        force, torque, depth = contact[:3], contact[3:6], float(contact[6])
        f = float(np.linalg.norm(force))
        if f <= 0.0 or not np.isfinite(f):
            self.release()
            return None
        link_pose = self.link.pose
        origin = np.asarray(link_pose.p, np.float64)
        point = origin + np.cross(force, torque) / f**2  # centre of pressure: on F's line of action
        stiffness = GAIN * f / max(depth, MIN_DEPTH)
        frame = sapien.Pose(point.astype(np.float32), matrix_to_quat(_frame_along(force / f)).astype(np.float32))
        self.drive.set_pose_in_child(link_pose.inv() * frame)
        self.drive.set_pose_in_parent(frame if self.parent is None else self.parent.pose.inv() * frame)
        # x: the link's offset along n from where F was computed; pushed while x < f / K
        self.drive.set_limit_x(f / stiffness, float(self._free[1]), stiffness, 0.0)
        self.active = True
        return force.copy(), point


def _frame_along(n: np.ndarray) -> np.ndarray:
    """A rotation matrix whose x axis is the unit vector ``n``."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    y = np.cross(helper, n)
    y /= np.linalg.norm(y)
    return np.stack([n, y, np.cross(n, y)], axis=1)
