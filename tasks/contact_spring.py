"""The pads' reaction on a two-way object as a spring that PhysX integrates implicitly.

A pad pressed on a free object pushes it with the force F(x) of the MPM layer. Applied as an
external force, one SAPIEN step late, that is an explicit spring: with a light object
(10-50 g) and a crushed pad's contact stiffness (1e4-1e5 N/m) it is stable only for SAPIEN
steps below about 2 sqrt(m/k).

:class:`ContactSpring` hands the same force to PhysX as a one-sided spring instead: a D6
joint between the world and the object, limited along the force's line of action with a
soft limit that PhysX's solver treats implicitly, like a joint drive:

* at the pose the MPM force was computed at, the spring pushes with exactly ``|F|`` along
  ``n = F/|F|``, through the centre of pressure;
* when the object moves by ``s`` along ``-n`` during the SAPIEN step (further into the pad),
  the force grows by ``K s`` within that same step, with ``K = GAIN |F| / δ`` (δ the pad's
  indentation): the secant stiffness of the contact times :data:`GAIN`;
* it never pulls: past the limit the joint is free.

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

__all__ = ["ContactSpring", "GAIN", "MIN_DEPTH", "centre_of_pressure"]

#: spring stiffness over the contact's secant stiffness |F|/δ (see the module docstring)
GAIN = 3.0
#: smallest indentation [m] used for the stiffness (a graze with no measured depth)
MIN_DEPTH = 1.0e-5


class ContactSpring:
    """One pad link's contact with one two-way object, as a one-sided spring along the MPM
    force's line of action that PhysX integrates with the object's motion (the other end
    is the world).

    Args:
        sub_scene: the SAPIEN scene of one env.
        body: the object's entity.
    """

    def __init__(self, sub_scene, body):
        self.body = body
        self.drive = sub_scene.create_drive(None, sapien.Pose(), body, sapien.Pose())
        self._free = self.drive.get_limit_x()  # unlimited, as created
        self.active = False

    def release(self) -> None:
        """No force until the next :meth:`update` with contact."""
        if self.active:
            self.drive.set_limit_x(*self._free)
            self.active = False

    def update(self, force: np.ndarray, point: np.ndarray, depth: float) -> bool:
        """Set the spring for the coming SAPIEN step from a contact of the last MPM step,
        computed at the object's pose now.

        Args:
            force: [3] force [N] the pad exerted on the object (world frame).
            point: [3] a world point [m] on its line of action.
            depth: the pad's indentation [m].

        Returns:
            whether the spring acts (``False``: no force, spring released).
        """
        f = float(np.linalg.norm(force))
        if f <= 0.0 or not np.isfinite(f):
            self.release()
            return False
        stiffness = GAIN * f / max(float(depth), MIN_DEPTH)
        frame = sapien.Pose(np.asarray(point, np.float32), matrix_to_quat(_frame_along(force / f)).astype(np.float32))
        self.drive.set_pose_in_child(self.body.pose.inv() * frame)
        self.drive.set_pose_in_parent(frame)
        # x: the body's offset along n from where F was computed; pushed while x < f / K
        self.drive.set_limit_x(f / stiffness, float(self._free[1]), stiffness, 0.0)
        self.active = True
        return True


def centre_of_pressure(force: np.ndarray, moment: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """The point of a force's line of action nearest ``origin`` [m], from the force [N] and
    its moment about ``origin`` [N·m] (world frame)."""
    return origin + np.cross(force, moment) / float(force @ force)


def _frame_along(n: np.ndarray) -> np.ndarray:
    """A rotation matrix whose x axis is the unit vector ``n``."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    y = np.cross(helper, n)
    y /= np.linalg.norm(y)
    return np.stack([n, y, np.cross(n, y)], axis=1)
