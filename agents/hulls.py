"""Pad meshes of ManiSkill hands whose fingertip collision files SAPIEN turns into a convex hull,
and convex clipping for the rigid parts built around pads.

ManiSkill loads a ``<collision><mesh>`` as the **convex hull** of the file's vertices
(``URDFLoader.load_multiple_collisions_from_file = False``, its default for every hand
agent), so a non-convex or open fingertip file (the Allegro FSR hand's
``longer_finger_tip.obj``: a base plate and the finger; the D'Claw's ``finger_tip.obj``: a
plate, a cylinder and a half sphere as three open shells) collides as its hull. A GaussTac
pad on such a link is cut from that hull (watertight, what the object touches), written
once to the cache (``cache_path("pad_meshes", <key>)``, the key a digest of the URDF and
its mesh files) and named in ``PadSpec.mesh`` (the D'Claw's from a part of it:
:mod:`.dclaw`). Units: metres, link frame.
"""
from __future__ import annotations

import hashlib
import os

__all__ = ["collision_hull", "collision_hull_file", "clip_convex", "PAD_MESHES"]

#: Cache subfolder of the hull files.
PAD_MESHES = "pad_meshes"


def collision_hull(urdf: str, link: str):
    """Convex hull (``trimesh.Trimesh``, link frame, metres) of every ``<collision>``
    element of ``link`` in ``urdf`` (meshes and primitives with their origins): the
    shape SAPIEN collides with, up to ManiSkill's one-hull-per-element loading (the hull
    of several elements also fills the space between them).

    Raises:
        AssetError: the URDF, the link's geometry or a mesh file is missing.
        ConfigError: ``link`` is not a link of ``urdf``.
    """
    import trimesh

    from ..urdf import link_mesh

    return trimesh.convex.convex_hull(link_mesh(urdf, link).vertices)


def collision_hull_file(urdf: str, link: str, name: str | None = None) -> str:
    """:func:`collision_hull` written to the cache as an OBJ (once per content); its path.

    Args:
        urdf: the URDF.
        link: the link whose collision geometry is hulled.
        name: the file's name (default ``<link>_hull.obj``).
    """
    from ..cache import cache_dir
    from ..urdf import parse_urdf

    model = parse_urdf(urdf)
    key = hashlib.sha1(b"collision-hull-v1\0" + link.encode())
    with open(urdf, "rb") as f:
        key.update(f.read())
    for geom in model.geometry(link, "collision"):
        if geom.kind == "mesh":
            with open(model.mesh_path(geom), "rb") as f:
                key.update(f.read())
    out = cache_dir(PAD_MESHES, key.hexdigest()[:16]) / (name or f"{link}_hull.obj")
    if not out.is_file():
        tmp = out.with_name(f".{out.stem}.{os.getpid()}.tmp.obj")
        collision_hull(urdf, link).export(tmp)
        os.replace(tmp, out)
    return str(out)


def clip_convex(mesh, halfspaces):
    """The part of the convex ``mesh`` (``trimesh.Trimesh``) where every ``n · x <= d`` holds,
    for the rows ``(nx, ny, nz, d)`` of ``halfspaces`` [K, 4] (``n`` need not be unit): a new
    convex ``trimesh.Trimesh`` (its corners merged to 1 µm).

    Raises:
        ValueError: the part is empty or flat.
    """
    import numpy as np
    import trimesh
    from scipy.optimize import linprog
    from scipy.spatial import HalfspaceIntersection

    normals = mesh.face_normals
    offsets = np.einsum("ij,ij->i", normals, mesh.triangles[:, 0])
    cut = np.asarray(halfspaces, float).reshape(-1, 4)
    planes = np.vstack([np.column_stack([normals, -offsets]), np.column_stack([cut[:, :3], -cut[:, 3]])])
    A, b = planes[:, :3], planes[:, 3]  # A x + b <= 0
    # the deepest point (Chebyshev centre): maximise r with A x + r |A| <= -b
    lp = linprog([0, 0, 0, -1], A_ub=np.column_stack([A, np.linalg.norm(A, axis=1)]), b_ub=-b,
                 bounds=[(None, None)] * 3 + [(0, None)])
    if lp.status != 0 or lp.x[3] <= 1e-9:
        raise ValueError("clip_convex: the half-spaces leave no volume of the mesh")
    corners = HalfspaceIntersection(planes, lp.x[:3]).intersections
    corners = corners[trimesh.grouping.unique_rows(corners, digits=6)[0]]
    return trimesh.convex.convex_hull(corners)
