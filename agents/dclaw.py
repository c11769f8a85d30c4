"""``dclaw_gausstac``: ManiSkill's ROBEL D'Claw (``dclaw``, the hand of ``RotateValveLevel0-4-v1``)
with soft pads on its three fingertips, made with :func:`~gausstac_maniskill.agents.add_gausstac_pads`
(controllers, keyframes, joints and visuals are ManiSkill's ``dclaw``'s).

Pads ``f1``, ``f2``, ``f3`` on ``link_f1_3``, ``link_f2_3``, ``link_f3_3``, the distal links
(ManiSkill's ``tip_link_names``, ``link_f*_head``, are massless frames at the tip's end,
x = 84 mm, without geometry). Link frames: x runs along the finger to the tip, y is the
flexion axis of ``joint_f*_1``/``joint_f*_2``, and the root joint ``joint_f*_0`` swings the
finger about the link z, tangentially round the claw's axis: that swing turns the valve. The
finger's palmar side (towards the claw's axis, the side that meets the valve's arms) is
**+z on f1 and -z on f2, f3** (f1's frames are mirrored).

Collision geometry. ManiSkill's ``link_f*_3`` collides with ``finger_tip.obj``, three open
shells: a plate (x = 23.5-32.5 mm, 48 × 26 mm, the motor horn), a 10 mm-radius cylinder
(x = 33-73 mm) and a half-sphere cap (to x = 83 mm), which SAPIEN turns into one convex hull
tapering from the plate to the cap (at x = 50 mm it is 36 mm wide where the finger is 20 mm),
and two knuckle brackets (boxes). Cut from that hull, whose centre of mass lies near the plate
(x = 31 mm), a pad would reach the fingertip only as a strip seen 55° off its normal. The pads
are therefore cut from the hull of the cylinder and cap alone (:data:`DCLAW_TIP_HULL`, the
finger's own shape: the visual mesh is 20 mm thick there), and in SAPIEN ``link_f*_3``
collides with that hull's rigid core (:func:`~gausstac_maniskill.tactile.pad_core_meshes`: the
hull 3 mm inset, and the hull of its vertices off the pad, here cut behind the soft layer)
**plus** the plate (a box) and the two brackets, unchanged: :func:`dclaw_urdf` writes that
URDF (``gausstac_core = False``: the agent loads it as it is;
:func:`~gausstac_maniskill.agents.core_urdf` alone would drop the plate and brackets, which
are not part of the pad mesh). Links, joints, masses and visuals
are ManiSkill's.

Pads: axis the palmar normal (±z) tilted :data:`PAD_TILT_DEG` towards the tip (+x), cone
:data:`PAD_CONE_DEG` seen from the tip hull's centre of mass (x = 56 mm): the palmar pulp from
x = 50 mm over the cap's palmar half, wrapping 55° round onto both tangential flanks (|y| up
to 8 mm; the valve is turned both ways at level 4); the axis is 16° off the pad's mean
surface normal. In RotateValve with the stock claw, fingers lowered onto the valve and swung
about their root joints met its arms 10-33 mm from the tip's end, 91-98 % of the contacts on
the palmar half. Thickness 4 mm (the default: 4 cells at dx = 1 mm; on the tip's 10 mm
radius the rigid stop lies at 7 mm), Dragon Skin 10 (E = 0.26 MPa, ν = 0.48); about 14 800
particles per pad at dx = 1 mm. Taxels: :data:`DCLAW_LAYOUT`, 1.25 mm pitch as the default
layout's, 40 mm along the sensor x (towards the tip) because the pad's surface runs from
-10 to +20 mm along it around the sensor origin (the grid is centred there). f1's mirrored
link frame gives it a mirrored axis but the same sensor frame round the claw: on all three,
sensor y points the same way about the claw's axis.

No hand Gaussians: the splat camera draws the pads over SAPIEN's render of the claw.
Units: metres, kilograms, degrees where named ``_DEG``.
"""
from __future__ import annotations

import hashlib
import math
import os
import warnings

from mani_skill.agents.registration import register_agent
from mani_skill.agents.robots.dclaw.dclaw import DClaw

from ..config import SensorLayout
from ..errors import AssetError
from .base import add_gausstac_pads
from .hulls import PAD_MESHES, clip_convex

__all__ = ["DClawGaussTac", "DCLAW_URDF", "DCLAW_TWIN_URDF", "DCLAW_PAD_LINKS", "DCLAW_PAD_AXES", "DCLAW_PALMAR_Z",
           "DCLAW_TIP_HULL", "DCLAW_MISSING", "DCLAW_LAYOUT", "PAD_TILT_DEG", "PAD_CONE_DEG", "PLATE_END_X",
           "dclaw_urdf", "dclaw_tip_meshes"]

#: ManiSkill's D'Claw URDF (what ``dclaw`` loads).
DCLAW_URDF = DClaw.urdf_path
#: Pad name -> distal link.
DCLAW_PAD_LINKS = {"f1": "link_f1_3", "f2": "link_f2_3", "f3": "link_f3_3"}
#: Sign of the link z on each finger's palmar side (towards the claw's axis).
DCLAW_PALMAR_Z = {"link_f1_3": 1.0, "link_f2_3": -1.0, "link_f3_3": -1.0}
#: Tilt [deg] of the pad axis from the palmar normal towards the tip (+x), and the pad cone's
#: half-angle [deg].
PAD_TILT_DEG = 20.0
PAD_CONE_DEG = 55.0
#: ``finger_tip.obj``'s vertices up to this x [m] are the plate's (it ends at 32.5 mm, the
#: cylinder starts at 33 mm).
PLATE_END_X = 0.03275
#: The pads' taxel grid: 16 rows (across the finger) × 32 columns (along it) over 40 × 20 mm.
DCLAW_LAYOUT = SensorLayout(rows=16, cols=32, size=(0.04, 0.02))


def _tip_file(urdf: str) -> str:
    from ..urdf import parse_urdf

    model = parse_urdf(urdf)
    mesh = [g for g in model.geometry("link_f1_3", "collision") if g.kind == "mesh"]
    if len(mesh) != 1:
        raise AssetError(f"{urdf}: link_f1_3 should have one collision mesh (finger_tip.obj), has {len(mesh)}")
    return str(model.mesh_path(mesh[0]))


def dclaw_tip_meshes(urdf: str = DCLAW_URDF):
    """``(tip, plate)``: the convex hull of ``finger_tip.obj``'s cylinder and cap, and the
    plate's bounds ``[[x0, y0, z0], [x1, y1, z1]]`` (link frame, metres; the file has no
    ``<origin>``, as ManiSkill's URDF uses it).

    Raises:
        AssetError: the URDF or the mesh is missing.
    """
    import trimesh

    v = trimesh.load(_tip_file(urdf), force="mesh").vertices
    tip = trimesh.convex.convex_hull(v[v[:, 0] > PLATE_END_X])
    plate = v[v[:, 0] <= PLATE_END_X]
    return tip, [plate.min(0).tolist(), plate.max(0).tolist()]


def _tip_hull_file(urdf: str) -> str:
    """:func:`dclaw_tip_meshes`'s tip hull written to the cache (once per content); its path."""
    from ..cache import cache_dir

    key = hashlib.sha1(b"dclaw-tip-hull-v1\0" + repr(PLATE_END_X).encode())
    for path in (urdf, _tip_file(urdf)):
        with open(path, "rb") as f:
            key.update(f.read())
    out = cache_dir(PAD_MESHES, key.hexdigest()[:16]) / "dclaw_tip_hull.obj"
    if not out.is_file():
        tmp = out.with_name(f".{out.stem}.{os.getpid()}.tmp.obj")
        dclaw_tip_meshes(urdf)[0].export(tmp)
        os.replace(tmp, out)
    return str(out)


def _behind_pads(back, mesh, specs):
    """``back`` (the convex hull of the pad mesh's vertices off the pads, the second piece of
    :func:`~gausstac_maniskill.tactile.pad_core_meshes`) cut behind each pad's soft layer: by
    the plane normal to the pad's axis at ``(room - CORE_DEPTH * thickness) cos(cone_deg)``
    from the mesh's centre (``room``: the centre's distance to the nearest face plane), in
    front of which no point within the cone lies shallower than the rigid stop. On the
    tip's cylinder that hull runs along the surface (a cylinder is ruled), and uncut it
    would be rigid up to the surface over a tenth of the pad, at the cone's rim."""
    import numpy as np

    from ..tactile.pad import CORE_DEPTH

    centre = mesh.center_mass
    normals = mesh.face_normals
    room = float(np.min(np.einsum("ij,ij->i", normals, mesh.triangles[:, 0]) - normals @ centre))
    cuts = []
    for spec in specs:
        axis = np.asarray(spec.axis, float)
        h = (room - CORE_DEPTH * spec.thickness) * math.cos(math.radians(spec.cone_deg))
        cuts.append([*axis, axis @ centre + h])
    return clip_convex(back, cuts)


def dclaw_urdf(pads, urdf: str = DCLAW_URDF) -> str:
    """``urdf`` in which each pad's link collides with its rigid core (the pieces of
    :func:`~gausstac_maniskill.tactile.pad_core_meshes` for the link's pads and mesh, the back
    cut behind the pads by :func:`_behind_pads`) and,
    unchanged, with the plate of ``finger_tip.obj`` (a box) and the link's other
    ``<collision>`` elements (the knuckle brackets), one convex piece each; written once per
    content to ``cache_path("pad_meshes", <key>)``, its path. Every other element is ManiSkill's
    (mesh paths made absolute).

    Raises:
        AssetError: the URDF or a mesh is missing.
        ConfigError: a pad leaves no core.
    """
    import numpy as np
    import trimesh

    from ..cache import cache_dir
    from ..tactile import pad_core_meshes, pad_mesh
    from ..urdf import parse_urdf, primitive_mesh, write_urdf_with_meshes

    model = parse_urdf(urdf)
    _, (lo, hi) = dclaw_tip_meshes(urdf)
    plate = trimesh.creation.box(extents=np.subtract(hi, lo))
    plate.apply_translation(np.add(lo, hi) / 2)
    by_link: dict = {}
    for p in pads:
        by_link.setdefault(p.link, []).append(p)
    pieces = {}
    for link, specs in by_link.items():
        rigid = [plate]
        for geom in model.geometry(link, "collision"):
            if geom.kind != "mesh":  # the brackets
                m = primitive_mesh(geom, model.path.name)
                m.apply_transform(geom.origin)
                rigid.append(m)
        mesh = pad_mesh(specs[0], urdf)
        core = pad_core_meshes(specs, mesh, mesh_name=f"the pad mesh of {link!r}")
        pieces[link] = [core[0]] + [_behind_pads(piece, mesh, specs) for piece in core[1:]] + rigid
    key = hashlib.sha1(b"dclaw-core-v2\0")
    with open(urdf, "rb") as f:
        key.update(f.read())
    for link, meshes in sorted(pieces.items()):
        key.update(link.encode())
        for m in meshes:
            key.update(np.round(m.vertices, 9).tobytes())
    return str(write_urdf_with_meshes(urdf, cache_dir(PAD_MESHES, key.hexdigest()[:16]), pieces))


def _axis(link: str) -> tuple:
    t = math.radians(PAD_TILT_DEG)
    return (round(math.sin(t), 9), 0.0, round(DCLAW_PALMAR_Z[link] * math.cos(t), 9))


#: Outward pad direction per link, in the link frame.
DCLAW_PAD_AXES = {link: _axis(link) for link in DCLAW_PAD_LINKS.values()}


def _make_twin():
    tip_hull = _tip_hull_file(DCLAW_URDF)
    cls = add_gausstac_pads(
        "dclaw", DCLAW_PAD_LINKS, uid="dclaw_gausstac", axes=DCLAW_PAD_AXES, register=False,
        cone_deg=PAD_CONE_DEG, mesh=tip_hull, along=(1.0, 0.0, 0.0), layout=DCLAW_LAYOUT)
    cls.__module__ = __name__
    cls.__qualname__ = "DClawGaussTac"
    cls.__doc__ = (
        "ROBEL D'Claw; pads ``f1``, ``f2``, ``f3`` (4 mm Dragon Skin 10, E = 0.26 MPa, nu = 0.48) on the palmar "
        "pulp of the distal links ``link_f*_3`` (axis: the palmar normal tilted 20 deg to the tip, cone 55 deg). "
        "Action (``pd_joint_pos``): joint_f1_0, f2_0, f3_0, f1_1, ..., f3_2 [rad], as ManiSkill's ``dclaw``.")
    # SAPIEN loads dclaw_urdf (the distal links' cores, plates and brackets) as it is
    twin_urdf = dclaw_urdf(cls.gausstac_pads)
    cls.urdf_path = twin_urdf
    cls.gausstac_core = False
    register_agent(override=True)(cls)
    return cls, tip_hull, twin_urdf


try:
    #: The twin; its fingertips' pad mesh (the convex hull of ``finger_tip.obj``'s cylinder and
    #: cap, link frame, metres; the three distal links' geometry is the same); the URDF SAPIEN
    #: loads (:func:`dclaw_urdf`). None, with :data:`DCLAW_MISSING` saying why, where
    #: ManiSkill's D'Claw asset is missing.
    DClawGaussTac, DCLAW_TIP_HULL, DCLAW_TWIN_URDF = _make_twin()
    DCLAW_MISSING = ""
except AssetError as e:
    DClawGaussTac = DCLAW_TIP_HULL = DCLAW_TWIN_URDF = None
    DCLAW_MISSING = f"dclaw_gausstac is not registered: {e}"
    warnings.warn(DCLAW_MISSING)
