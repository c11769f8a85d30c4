"""``allegro_hand_right_touch_gausstac``: ManiSkill's Allegro right hand with FSR touch sensors
(``allegro_hand_right_touch``, the hand of ``RotateSingleObjectInHandLevel0-3-v1``) with soft
pads on its four fingertips, made with :func:`~gausstac_maniskill.agents.add_gausstac_pads`;
its 16 FSR sensor links and their ``fsr_impulse`` reading are kept.

Pads ``thumb``, ``index``, ``middle``, ``ring`` on ``link_15.0_tip``, ``link_3.0_tip``,
``link_7.0_tip``, ``link_11.0_tip`` (the links, names, thickness and material of
``allegro_hand_right_gausstac``'s pads). The FSR hand's fingertips are not the plain Allegro's:
``longer_finger_tip.obj``, a 26 × 26 × 3 mm base plate and a 12 × 19 mm finger ending in a
rounded end at z = +4 mm (tip frame 60 mm along ``link_3.0``, the plain hand's at 26.7 mm; +x
palmar, +z towards the fingertip's end). SAPIEN collides with its convex hull (plate
included: it tapers from the plate to the end), and the pads are cut from that hull
(:data:`TOUCH_TIP_HULL`, written to the cache by
:func:`~gausstac_maniskill.agents.hulls.collision_hull_file`). Seen from the hull's centre of
mass (25 mm below the end), the palmar pulp lies towards the end: the axis is +x tilted
:data:`PAD_TILT_DEG` towards +z, cone :data:`PAD_CONE_DEG`; the pad runs along the palmar face from 34 to 3 mm
below the end (17° off its mean surface normal) and covers 86 % of the tip FSR's footprint. 4 mm Dragon Skin
10 (E = 0.26 MPa, ν = 0.48; the hull leaves 9.7 mm of room), about 17 300 particles per pad at
dx = 1 mm; sensor x towards the fingertip's end (the link z). Taxels: :data:`TOUCH_LAYOUT`, 1.25 mm
pitch as the default layout's, 45 mm along the sensor x because the pad's surface runs from
-10 to +22 mm along it around the sensor origin (the grid is centred there; the plain Allegro's
pad fits the default 20 mm).

FSR sensors (ManiSkill's ``AllegroHandRightTouch``): 12 finger links (``link_14.0_fsr``,
``link_15.0_fsr``, ``link_15.0_tip_fsr``, ``link_1.0_fsr``, ``link_2.0_fsr``, ``link_3.0_tip_fsr``,
... ``link_11.0_tip_fsr``) and 4 palm links (``link_base_fsr``, ``link_0.0_fsr``, ``link_4.0_fsr``,
``link_8.0_fsr``), each a fixed child link with one box (3 × 22.8 × 16.8 mm) whose SAPIEN
contact impulses are the reading (``get_fsr_impulse``, proprioception ``fsr_impulse`` [16]).
The pads are on other links, so every FSR link, its order and its reading stay. The 12 FSRs off
the fingertips are unchanged. The 4 tip FSRs (``link_*_tip_fsr``) sit on the palmar face of the
very tip the pad covers, its distal half standing up to 2 mm out of the tip's hull (its
proximal half lies inside it): left there, the rigid box would stop an object before the
soft layer compresses. In this twin each tip FSR lies **under
the silicone, on the rigid core**, as a sensor under a skin: its box is replaced by the
palmar part of the tip's core within the box's footprint (:func:`tip_fsr_mesh`), raised
:data:`TIP_FSR_LIFT` above the core so that it, not the tip's own core, takes an object that
presses through the layer. A tip FSR then reads the contact at the rigid stop (an object
that squeezed the 4 mm layer by 2.5 mm; 3 mm elsewhere on the pad); with ``pad_reaction=False`` (the default)
that is what SAPIEN's physics feels, as the stock FSR reads the stock tip's contacts; with
``pad_reaction`` the pads carry the load and a tip FSR reads only what reaches the core.
The twin loads :func:`touch_urdf`, the FSR URDF with those four boxes replaced, written to
the cache.

No hand Gaussians: ``allegro_hand_right``'s (``assets/allegro_hand_right``) are the plain
hand's tips; the splat camera draws the pads over SAPIEN's render of this hand.
Units: metres, degrees where named ``_DEG``.
"""
from __future__ import annotations

import hashlib
import math
import warnings

import numpy as np
from mani_skill.agents.registration import register_agent
from mani_skill.agents.robots.allegro_hand.allegro_touch import AllegroHandRightTouch

from ..config import SensorLayout
from ..errors import AssetError
from ..tactile import ALLEGRO_TIPS
from .allegro import ALLEGRO_PAD_NAMES
from .base import add_gausstac_pads
from .hulls import PAD_MESHES, clip_convex, collision_hull_file

__all__ = ["AllegroHandRightTouchGaussTac", "TOUCH_URDF", "TOUCH_TIP_HULL", "TOUCH_PAD_AXIS", "TIP_FSR_LINKS",
           "FSR_LINKS", "TOUCH_LAYOUT", "TOUCH_MISSING", "PAD_TILT_DEG", "PAD_CONE_DEG", "TIP_FSR_LIFT", "tip_fsr_mesh",
           "touch_urdf"]

#: ManiSkill's FSR Allegro URDF (``allegro_hand_right_touch``'s ``urdf_path``).
TOUCH_URDF = AllegroHandRightTouch.urdf_path
#: ManiSkill's FSR links, in ``AllegroHandRightTouch``'s order: palm, then fingers (thumb,
#: index, middle, ring, root to tip), as ``fsr_impulse`` lists them.
FSR_LINKS = ("link_base_fsr", "link_0.0_fsr", "link_4.0_fsr", "link_8.0_fsr",
             "link_14.0_fsr", "link_15.0_fsr", "link_15.0_tip_fsr", "link_1.0_fsr", "link_2.0_fsr",
             "link_3.0_tip_fsr", "link_5.0_fsr", "link_6.0_fsr", "link_7.0_tip_fsr", "link_9.0_fsr",
             "link_10.0_fsr", "link_11.0_tip_fsr")
#: Pad link -> the FSR link on its palmar face.
TIP_FSR_LINKS = {tip: f"{tip}_fsr" for tip in ALLEGRO_TIPS}
#: Tilt [deg] of the pad axis from the palmar normal (+x) towards the fingertip's end (+z),
#: and the pad cone's half-angle [deg].
PAD_TILT_DEG = 30.0
PAD_CONE_DEG = 55.0
TOUCH_PAD_AXIS = (round(math.cos(math.radians(PAD_TILT_DEG)), 9), 0.0,
                  round(math.sin(math.radians(PAD_TILT_DEG)), 9))
#: Height [m] of a tip FSR above the tip's rigid core (it is hit first there).
TIP_FSR_LIFT = 0.5e-3
#: The pads' taxel grid: 16 rows (across the finger) × 36 columns (along it) over 45 × 20 mm.
TOUCH_LAYOUT = SensorLayout(rows=16, cols=36, size=(0.045, 0.02))


def tip_fsr_mesh(spec, urdf: str = TOUCH_URDF, lift: float = TIP_FSR_LIFT):
    """The collision mesh (convex ``trimesh.Trimesh``, in the FSR link's frame, metres) of the
    tip FSR under ``spec``'s pad: the part of the pad link's rigid core (its inset piece,
    :func:`~gausstac_maniskill.tactile.pad_core_meshes`) on the palmar side (tip-frame x >= 0)
    within the stock FSR box's footprint (its y and z extent in the tip frame), moved ``lift``
    along +x.

    Raises:
        AssetError: the URDF or a mesh is missing.
    """
    from ..tactile import pad_core_meshes, pad_mesh
    from ..urdf import link_mesh, parse_urdf

    fsr = TIP_FSR_LINKS[spec.link]
    joint = next(j for j in parse_urdf(urdf).joints if j.child == fsr)
    assert joint.parent == spec.link and joint.type == "fixed", joint
    T = joint.origin  # FSR frame -> tip frame
    box = link_mesh(urdf, fsr).vertices @ T[:3, :3].T + T[:3, 3]
    (_, y0, z0), (_, y1, z1) = box.min(0), box.max(0)
    core = pad_core_meshes(spec, pad_mesh(spec, urdf))[0]
    slab = clip_convex(core, [[0, 1, 0, y1], [0, -1, 0, -y0], [0, 0, 1, z1], [0, 0, -1, -z0], [-1, 0, 0, 0]])
    slab.apply_translation([lift, 0.0, 0.0])
    slab.apply_transform(np.linalg.inv(T))
    return slab


def touch_urdf(pads, urdf: str = TOUCH_URDF) -> str:
    """``urdf`` with each tip FSR's box replaced by :func:`tip_fsr_mesh` of the pad on its
    tip, written once per content to ``cache_path("pad_meshes", <key>)``; its path. Every
    other link (the 12 other FSRs included) is ManiSkill's."""
    from ..cache import cache_dir
    from ..urdf import write_urdf_with_meshes

    meshes = {TIP_FSR_LINKS[p.link]: tip_fsr_mesh(p, urdf) for p in pads if p.link in TIP_FSR_LINKS}
    key = hashlib.sha1(b"touch-fsr-under-pad-v1\0")
    with open(urdf, "rb") as f:
        key.update(f.read())
    for link, mesh in sorted(meshes.items()):
        key.update(link.encode() + np.round(mesh.vertices, 9).tobytes())
    folder = cache_dir(PAD_MESHES, key.hexdigest()[:16])
    return str(write_urdf_with_meshes(urdf, folder, {link: [mesh] for link, mesh in meshes.items()}))


def _make_twin():
    tip_hull = collision_hull_file(TOUCH_URDF, "link_3.0_tip", "allegro_touch_tip_hull.obj")
    cls = add_gausstac_pads(
        "allegro_hand_right_touch", dict(zip(ALLEGRO_PAD_NAMES, ALLEGRO_TIPS)), uid="allegro_hand_right_touch_gausstac",
        urdf=TOUCH_URDF, register=False, axis=TOUCH_PAD_AXIS, cone_deg=PAD_CONE_DEG, mesh=tip_hull,
        layout=TOUCH_LAYOUT)
    cls.__module__ = __name__
    cls.__qualname__ = "AllegroHandRightTouchGaussTac"
    cls.__doc__ = (
        "Allegro right hand with FSR sensors; pads ``thumb``, ``index``, ``middle``, ``ring`` (4 mm Dragon Skin 10, "
        "E = 0.26 MPa, nu = 0.48) on the palmar pulp of the fingertips (axis: +x tilted 30 deg to the end, cone "
        "55 deg), the 4 tip FSRs under them on the rigid core; proprioception ``fsr_impulse`` [16] as ManiSkill's "
        "``allegro_hand_right_touch``. Action (``pd_joint_pos``): joint_0.0 ... joint_15.0 [rad].")
    # SAPIEN loads the FSR URDF with the tip FSRs under the pads (then their cores, GaussTacAgent)
    cls.urdf_path = touch_urdf(cls.gausstac_pads)
    register_agent(override=True)(cls)
    return cls, tip_hull


try:
    #: The twin, and the pad mesh of its four fingertips (the same collision geometry: the
    #: convex hull of ``longer_finger_tip.obj``, tip frame, metres). None, with
    #: :data:`TOUCH_MISSING` saying why, where ManiSkill's FSR Allegro asset is missing.
    AllegroHandRightTouchGaussTac, TOUCH_TIP_HULL = _make_twin()
    TOUCH_MISSING = ""
except AssetError as e:
    AllegroHandRightTouchGaussTac = TOUCH_TIP_HULL = None
    TOUCH_MISSING = f"allegro_hand_right_touch_gausstac is not registered: {e}"
    warnings.warn(TOUCH_MISSING)
