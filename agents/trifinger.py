"""``trifingerpro_gausstac``: ManiSkill's TriFinger Pro (``trifingerpro``, the robot of
``TriFingerRotateCubeLevel0-4-v1``) with soft pads on its three fingertips, made with
:func:`~gausstac_maniskill.agents.add_gausstac_pads` (the agent, its URDF ``trifingerpro.urdf``
and controllers are ManiSkill's).

Pads ``f0``, ``f120``, ``f240`` on ``finger_tip_link_0`` / ``_120`` / ``_240`` (ManiSkill's
``tip_link_names``). A tip link's collision mesh ``tip_sim.stl`` is a 10 mm-radius sphere
centred on the link origin on an 8.5 mm-radius stem running up the finger (+z, to z = 21.5 mm);
watertight, the pads are cut from it as it is (on the pad it coincides with the convex hull
SAPIEN collides with). The three tip frames are alike: the flexion axes of the finger's two
distal joints are x, the finger's inner (palmar) side, which faces the cube when the
fingers close on it, is -y, and -z points away from the finger, beyond the tip.

Axis: -y tilted :data:`PAD_TILT_DEG` downwards (towards -z), cone :data:`PAD_CONE_DEG`, seen from
the mesh's centre of mass (z = 6.2 mm above the sphere's centre): the pad covers the sphere's
inner side from the stem (z = 8 mm) to the bottom (1 mm past it), 14° off its mean surface normal. Driving
the three tips at the cube (ManiSkill's TriFingerRotateCube, stock robot), all but 1 of 1 394
fingertip-cube contacts lay in the cone (on the inner side, 90 % of them 2-42° below the
horizontal and within 52° of -y sideways); a tip pressing down on the cube's top meets it
too. Thickness 4 mm (the default, 4 cells at dx = 1 mm; the tip leaves 9.5 mm of room, the
rigid stop lies 3 mm in), Dragon Skin 10
(E = 0.26 MPa, ν = 0.48); about 12 400 particles per pad at dx = 1 mm. Taxels:
:data:`TRIFINGER_LAYOUT`, 1.25 mm pitch as the default layout's, 30 mm along the sensor x
(towards the tip's end, -z) because the pad's surface runs from -7 to +13 mm along it around
the sensor origin (the grid is centred there).

No hand Gaussians: the splat camera draws the pads over SAPIEN's render of the robot.
Units: metres, degrees where named ``_DEG``.
"""
from __future__ import annotations

import math
import warnings

from mani_skill.agents.registration import register_agent
from mani_skill.agents.robots.trifingerpro.trifingerpro import TriFingerPro

from ..config import SensorLayout
from ..errors import AssetError
from .base import add_gausstac_pads

__all__ = ["TriFingerProGaussTac", "TRIFINGER_PAD_LINKS", "TRIFINGER_PAD_AXIS", "TRIFINGER_LAYOUT", "TRIFINGER_MISSING",
           "PAD_TILT_DEG", "PAD_CONE_DEG"]

#: ManiSkill's TriFinger Pro URDF (what ``trifingerpro`` loads).
TRIFINGER_URDF = TriFingerPro.urdf_path
#: Pad name -> fingertip link.
TRIFINGER_PAD_LINKS = {"f0": "finger_tip_link_0", "f120": "finger_tip_link_120", "f240": "finger_tip_link_240"}
#: Tilt [deg] of the pad axis from the inner side (-y) towards -z, and the cone half-angle [deg].
PAD_TILT_DEG = 40.0
PAD_CONE_DEG = 55.0
#: The pads' taxel grid: 16 rows × 24 columns (along the sensor x) over 30 × 20 mm.
TRIFINGER_LAYOUT = SensorLayout(rows=16, cols=24, size=(0.03, 0.02))
#: Outward pad direction in each tip's frame.
TRIFINGER_PAD_AXIS = (0.0, round(-math.cos(math.radians(PAD_TILT_DEG)), 9),
                      round(-math.sin(math.radians(PAD_TILT_DEG)), 9))


def _make_twin():
    cls = add_gausstac_pads(
        "trifingerpro", TRIFINGER_PAD_LINKS, uid="trifingerpro_gausstac", register=False,
        axis=TRIFINGER_PAD_AXIS, cone_deg=PAD_CONE_DEG, along=(0.0, 0.0, -1.0), layout=TRIFINGER_LAYOUT)
    cls.__module__ = __name__
    cls.__qualname__ = "TriFingerProGaussTac"
    cls.__doc__ = (
        "TriFinger Pro; pads ``f0``, ``f120``, ``f240`` (4 mm Dragon Skin 10, E = 0.26 MPa, nu = 0.48) on the inner "
        "lower quarter of the spherical tips (axis: -y tilted 40 deg down, cone 55 deg). Action (``pd_joint_pos``): "
        "per finger base_to_upper, upper_to_middle, middle_to_lower [rad], as ManiSkill's ``trifingerpro``.")
    register_agent(override=True)(cls)
    return cls


try:
    #: The twin; None, with :data:`TRIFINGER_MISSING` saying why, where ManiSkill's TriFinger
    #: asset is missing.
    TriFingerProGaussTac = _make_twin()
    TRIFINGER_MISSING = ""
except AssetError as e:
    TriFingerProGaussTac = None
    TRIFINGER_MISSING = f"trifingerpro_gausstac is not registered: {e}"
    warnings.warn(TRIFINGER_MISSING)
