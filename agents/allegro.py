"""``allegro_hand_right_gausstac``: ManiSkill's Allegro right hand with soft pads on its
four fingertips (``allegro_hand_right_touch_gausstac`` is the FSR hand's twin, :mod:`.allegro_touch`), and
``floating_allegro_hand_right_gausstac``: the same hand on a 6-DoF floating root, for tasks
that pick things up."""
from __future__ import annotations

import copy

import numpy as np
import sapien
from mani_skill.agents.base_agent import Keyframe
from mani_skill.agents.controllers import PDJointPosControllerConfig
from mani_skill.agents.registration import register_agent
from mani_skill.agents.robots.allegro_hand.allegro import AllegroHandRight

from ..assets import asset_path
from ..config import PadSpec
from ..tactile import ALLEGRO_TIPS
from ..urdf import default_hand_urdf
from .base import GaussTacAgent

__all__ = ["AllegroHandRightGaussTac", "FloatingAllegroHandRightGaussTac", "ALLEGRO_PAD_NAMES",
           "floating_allegro_urdf", "FLOATING_ROOT_DRIVE", "FLOATING_ROOT_DELTA", "ALLEGRO_PINCH_CENTRE",
           "ALLEGRO_PINCH_AXIS", "pinch_down_rotation"]

#: Pad ids of the Allegro tips, in ``ALLEGRO_TIPS`` order (thumb, index, middle, ring).
ALLEGRO_PAD_NAMES = ("thumb", "index", "middle", "ring")


@register_agent(override=True)
class AllegroHandRightGaussTac(GaussTacAgent, AllegroHandRight):
    """Allegro right hand; pads ``thumb``, ``index``, ``middle``, ``ring`` (4 mm Dragon Skin 10
    silicone, E = 0.26 MPa, ν = 0.48, 16×16 taxels over 20 mm) on the palmar side (+x) of the tips."""

    uid = "allegro_hand_right_gausstac"
    gausstac_pads = tuple(PadSpec(link=link, name=name) for link, name in zip(ALLEGRO_TIPS, ALLEGRO_PAD_NAMES))
    gausstac_urdf = default_hand_urdf()
    gausstac_gaussians = str(asset_path("allegro_hand_right"))


def floating_allegro_urdf() -> str:
    """ManiSkill's Allegro right hand (``allegro_hand_right_glb.urdf``) hanging from the 6-DoF
    root chain of :func:`~gausstac_maniskill.urdf.write_floating_urdf`, written once to
    the cache; its path."""
    import hashlib

    from ..cache import cache_dir
    from ..urdf import write_floating_urdf

    src = AllegroHandRight.urdf_path
    with open(src, "rb") as f:
        key = hashlib.sha1(f.read() + b"floating-v1").hexdigest()[:16]
    out = cache_dir("floating", key) / "allegro_hand_right_floating.urdf"
    if not out.is_file():
        write_floating_urdf(src, out)
    return str(out)


#: Root drives of the floating Allegro: (stiffness, damping, force limit) of the prismatic
#: joints [N/m, N·s/m, N] and of the revolute ones [N·m/rad, N·m·s/rad, N·m]. Stiff enough
#: that the 1.1 kg hand sags 1 mm under its own weight, and a 500 g object held 0.15 m out
#: tilts it by under 1 mrad.
FLOATING_ROOT_DRIVE = ((1.0e4, 2.0e2, 200.0), (2.0e3, 2.0e1, 50.0))
#: Largest root step per control step of the delta controllers: translation [m], rotation [rad].
FLOATING_ROOT_DELTA = (0.01, 0.05)


#: The thumb-index pinch of the Allegro hand, in its base frame (``base_link``) [m]: the
#: point between the thumb and index pads and the axis from the thumb's pad to the index's.
#: Chosen by least squares over both fingers' joints and this point, for cubes of half size
#: 10, 20, 30 and 40 mm centred here (pad apices on opposite faces, pad normals opposed);
#: IK on position and pad normal then reaches the faces to within 3 mm and 10° (the thumb
#: at 10 mm; ``tests/agents/test_floating_allegro.py`` checks 20 mm).
ALLEGRO_PINCH_CENTRE = (0.105, 0.096, -0.028)
ALLEGRO_PINCH_AXIS = (0.0, 0.0, 1.0)


def pinch_down_rotation() -> np.ndarray:
    """[3, 3] base_link -> world rotation that puts the pinch axis along world +y and the
    pinch point straight below the hand's base (the hand reaching down to an object on a
    table, thumb on its -y side). Its root angles (:meth:`FloatingAllegroHandRightGaussTac.root_qpos`)
    are far from the x-y-z chain's gimbal lock (rotation about y of ±90°)."""
    u = np.asarray(ALLEGRO_PINCH_AXIS, float)
    c = np.asarray(ALLEGRO_PINCH_CENTRE, float)
    down = c - (c @ u) * u
    down /= np.linalg.norm(down)
    hand = np.stack([down, u, np.cross(down, u)], axis=1)  # right-handed, in the hand frame
    world = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]).T  # down, u, down x u in the world
    return world @ hand.T


@register_agent(override=True)
class FloatingAllegroHandRightGaussTac(AllegroHandRightGaussTac):
    """The Allegro right hand with GaussTac pads on a floating 6-DoF root (an arm's wrist
    reduced to PD drives on x, y, z [m] and rotations about x, y, z [rad], as ManiSkill's
    floating hands): it can lift what it grasps.

    Action (``pd_joint_pos``): the six root joints
    (:data:`~gausstac_maniskill.urdf.FLOATING_JOINTS`, hand pose = translation · Rx · Ry · Rz)
    then ``joint_0.0`` ... ``joint_15.0``. The delta modes step the root at most
    :data:`FLOATING_ROOT_DELTA` and the fingers 0.1 rad per control step. Root drives:
    :data:`FLOATING_ROOT_DRIVE`; finger drives: ManiSkill's Allegro (400 N·m/rad, 10, 50 N·m).
    """

    uid = "floating_allegro_hand_right_gausstac"
    urdf_path = floating_allegro_urdf()
    keyframes = dict(rest=Keyframe(qpos=np.zeros(22), pose=sapien.Pose()))

    @property
    def _controller_configs(self):
        from ..urdf import FLOATING_JOINTS

        names = list(FLOATING_JOINTS) + list(self.joint_names)
        (kt, dt, ft), (kr, dr, fr) = FLOATING_ROOT_DRIVE
        per = lambda root_t, root_r, finger: [root_t] * 3 + [root_r] * 3 + [finger] * len(self.joint_names)  # noqa: E731
        gains = dict(stiffness=per(kt, kr, self.joint_stiffness), damping=per(dt, dr, self.joint_damping),
                     force_limit=per(ft, fr, self.joint_force_limit))
        step_t, step_r = FLOATING_ROOT_DELTA
        low, high = per(-step_t, -step_r, -0.1), per(step_t, step_r, 0.1)
        joint_pos = PDJointPosControllerConfig(names, None, None, normalize_action=False, **gains)
        delta = PDJointPosControllerConfig(names, low, high, use_delta=True, **gains)
        target_delta = copy.deepcopy(delta)
        target_delta.use_target = True
        return dict(pd_joint_pos=joint_pos, pd_joint_delta_pos=delta, pd_joint_target_delta_pos=target_delta)

    @staticmethod
    def root_qpos(pose: np.ndarray) -> np.ndarray:
        """[6] root joint values (x, y, z [m], rotations about x, y, z [rad]) that put the
        hand's base at world ``pose`` [4, 4] (agent at the world origin)."""
        from scipy.spatial.transform import Rotation

        pose = np.asarray(pose, np.float64)
        return np.concatenate([pose[:3, 3], Rotation.from_matrix(pose[:3, :3]).as_euler("XYZ")])

    @staticmethod
    def base_pose(root_qpos) -> np.ndarray:
        """[4, 4] world pose of the hand's base for root joint values ``root_qpos`` [6]
        (inverse of :meth:`root_qpos`)."""
        from scipy.spatial.transform import Rotation

        q = np.asarray(root_qpos, np.float64)
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("XYZ", q[3:6]).as_matrix()
        T[:3, 3] = q[:3]
        return T
