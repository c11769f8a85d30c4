"""``floating_ability_hand_right_gausstac``: ManiSkill's floating PSYONIC Ability hand
(``floating_ability_hand_right``) with soft pads on its five distal phalanges, made with
:func:`~gausstac_maniskill.agents.add_gausstac_pads` (the agent, its URDF, controllers
and SAPIEN collisions are ManiSkill's, unchanged).

Pads on ``thumb_L2`` and ``index_L2`` / ``middle_L2`` / ``ring_L2`` / ``pinky_L2`` (link
frames of ``ability_hand_right_floating.urdf``; flexion axis = link z, the ``*_tip`` point
at (65, 16, 0) mm on the thumb, (35, -18, 0) mm on the fingers). The pad axis is the
phalanx's palmar normal (``z × tip``) tilted towards the tip, so the pad covers the pulp:
fingers 20° (45° cone), thumb 40° (30° cone). The thumb's pad is cut from its convex
collision mesh (``thumb-F2_C.obj``); a finger's from the convex hull of ``idx-F2_C.obj``
(not watertight as loaded) and a 7 mm tip sphere, which is what SAPIEN collides with
(``assets/ability_hand_right/finger_L2_hull.obj``, :func:`write_finger_hull`).

No hand Gaussians: the splat camera draws the pads over SAPIEN's render of the hand.
"""
from __future__ import annotations

import math
import os

import numpy as np
import sapien
from mani_skill.agents.base_agent import Keyframe
from mani_skill.agents.registration import register_agent

from ..assets import asset_path
from .base import add_gausstac_pads

__all__ = ["ABILITY_PAD_LINKS", "ABILITY_PAD_AXES", "ABILITY_URDF", "ABILITY_FINGER_HULL", "finger_hull_mesh",
           "FloatingAbilityHandRightGaussTac", "write_finger_hull"]


def _ability_urdf() -> str:
    import mani_skill

    return os.path.join(str(mani_skill.PACKAGE_ASSET_DIR), "robots", "ability_hand",
                        "ability_hand_right_floating.urdf")


#: The floating right-hand URDF the agent ``floating_ability_hand_right`` loads.
ABILITY_URDF = _ability_urdf()
#: Pad name -> distal phalanx link.
ABILITY_PAD_LINKS = {"thumb": "thumb_L2", "index": "index_L2", "middle": "middle_L2", "ring": "ring_L2",
                     "pinky": "pinky_L2"}
#: The watertight pad mesh of the four fingers' distal phalanges (link frame, metres).
ABILITY_FINGER_HULL = str(asset_path("ability_hand_right", "finger_L2_hull.obj"))
#: Tip points of the distal phalanges in their link frames [m] (the URDF's ``*_tip_joint`` origins).
_TIP = {"thumb_L2": (0.065, 0.016, 0.0), "finger": (0.035, -0.018, 0.0)}
#: Tilt of the pad axis from the palmar normal towards the tip [deg], and the pad cone
#: half-angle [deg], of the thumb and of the fingers.
PAD_TILT_DEG = {"thumb_L2": 40.0, "finger": 20.0}
PAD_CONE_DEG = {"thumb_L2": 30.0, "finger": 45.0}
#: ``q2 = 1.05851325 q1 + 0.72349796``: the distal joints of the fingers at q1 = 0 (open hand)
#: under ManiSkill's mimic controller.
_Q2_OPEN = 0.72349796


def _kind(link: str) -> str:
    return "thumb_L2" if link == "thumb_L2" else "finger"


def _pad_axis(tip, tilt_deg: float) -> tuple:
    """Palmar normal (flexion axis z × tip direction) tilted ``tilt_deg`` towards the tip."""
    along = np.asarray(tip, float) / np.linalg.norm(tip)
    palmar = np.cross([0.0, 0.0, 1.0], along)
    a = math.radians(tilt_deg)
    v = math.cos(a) * palmar + math.sin(a) * along
    return tuple(float(c) for c in np.round(v / np.linalg.norm(v), 6))


#: Outward pad direction per link, in the link frame.
ABILITY_PAD_AXES = {link: _pad_axis(_TIP[_kind(link)], PAD_TILT_DEG[_kind(link)])
                    for link in ABILITY_PAD_LINKS.values()}


def finger_hull_mesh(urdf: str = ABILITY_URDF):
    """Convex hull (``trimesh.Trimesh``, link frame) of a finger distal phalanx's collision
    geometry in ``urdf``: the hull of ``idx-F2_C.obj`` and the 7 mm-radius tip sphere."""
    import trimesh

    from ..urdf import link_mesh

    mesh = link_mesh(urdf, "index_L2")  # the mesh + the sphere, concatenated
    return trimesh.convex.convex_hull(mesh.vertices)


def write_finger_hull(path: str = ABILITY_FINGER_HULL, urdf: str = ABILITY_URDF) -> str:
    """(Re)write the finger pad mesh :data:`ABILITY_FINGER_HULL` from ManiSkill's URDF."""
    mesh = finger_hull_mesh(urdf)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    mesh.export(path)
    return path


def _per_link_fields() -> dict:
    """Per-pad fields: the cone, and the fingers' mesh :data:`ABILITY_FINGER_HULL` (derived
    from ManiSkill's URDF: written here if it is missing; if it cannot be, building the
    pads raises AssetError naming PadSpec.mesh)."""
    if not os.path.isfile(ABILITY_FINGER_HULL):
        try:
            write_finger_hull()
        except OSError:
            pass
    # sensor x "along the finger" = towards the tip (the link z is the flexion axis here)
    return {link: dict(cone_deg=PAD_CONE_DEG[_kind(link)], mesh=None if link == "thumb_L2" else ABILITY_FINGER_HULL,
                       along=tuple(float(v) for v in _TIP[_kind(link)]))
            for link in ABILITY_PAD_LINKS.values()}


FloatingAbilityHandRightGaussTac = add_gausstac_pads(
    "floating_ability_hand_right", ABILITY_PAD_LINKS, uid="floating_ability_hand_right_gausstac",
    axes=ABILITY_PAD_AXES, per_link=_per_link_fields(), register=False)
FloatingAbilityHandRightGaussTac.__module__ = __name__
FloatingAbilityHandRightGaussTac.__qualname__ = "FloatingAbilityHandRightGaussTac"
FloatingAbilityHandRightGaussTac.__doc__ = (
    "Floating Ability right hand; pads ``thumb``, ``index``, ``middle``, ``ring``, ``pinky`` (4 mm Dragon Skin 10, "
    "E = 0.26 MPa, ν = 0.48) on the palmar side of the distal phalanges. Action (``pd_joint_pos``): "
    "root x, y, z [m], rx, ry, rz [rad]; index, middle, ring, pinky q1 (q2 follows by mimic); thumb q1, q2.")
#: ``rest``: root at the origin, hand open (finger q2 at the mimic controller's q1 = 0 value,
#: so a zero finger action holds the pose).
FloatingAbilityHandRightGaussTac.keyframes = dict(
    rest=Keyframe(qpos=np.array([0.0] * 12 + [_Q2_OPEN] * 4), pose=sapien.Pose(p=[0, 0, 0])))
register_agent(override=True)(FloatingAbilityHandRightGaussTac)
