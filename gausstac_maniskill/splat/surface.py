"""Coloured link surfaces of a URDF, sampled into flat 3D Gaussians.

:func:`load_link_meshes` gives every link's visual meshes (files or
box/cylinder/sphere primitives) in the link frame with a colour source
(texture > vertex/face colours > mesh material > URDF ``rgba`` > grey);
:func:`sample_surface_blue_noise` puts roughly even samples on them (≈ area / spacing²)
and :func:`gaussians_from_surface` one disc Gaussian on every sample.

Units: metres; colours RGB in [0, 1].
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from ..errors import AssetError, ConfigError
from ..urdf import URDFModel, primitive_mesh
from .gaussians import GaussianSet, rotmat_to_quat
from .sh import rgb_to_sh_dc

__all__ = [
    "IN_PLANE_SCALE",
    "NORMAL_SCALE",
    "OPACITY_LOGIT",
    "GREY",
    "ColoredMesh",
    "colored_mesh",
    "load_link_meshes",
    "sample_surface_blue_noise",
    "closed_outward",
    "gaussians_from_surface",
    "gaussians_from_points",
]

IN_PLANE_SCALE = 0.9      #: in-plane σ / spacing (see :func:`gaussians_from_surface`)
NORMAL_SCALE = 1.0 / 20   #: normal σ / spacing
OPACITY_LOGIT = 4.0       #: opacity sigmoid(4) ≈ 0.982
THIN_RADIUS = 0.65        #: blue-noise exclusion radius / spacing
OVERSAMPLE = 4            #: candidates per target sample
GREY = (0.5, 0.5, 0.5)    #: colour of surfaces without any colour source


# =========================================================================== meshes
@dataclass
class ColoredMesh:
    """A triangle mesh in its link's frame with a colour source.

    Attributes:
        mesh: the ``trimesh.Trimesh``, metres.
        colors: ``colors(face_index [n], points [n, 3])`` -> [n, 3] RGB in [0, 1]
            at surface points.
        source: where the colour comes from: ``"texture" | "vertex" | "face" |
            "material" | "urdf" | "grey"``.
    """

    mesh: "object"  # trimesh.Trimesh
    colors: Callable[[np.ndarray, np.ndarray], np.ndarray]
    source: str


def _const_colors(rgb) -> Callable:
    rgb = np.clip(np.asarray(rgb, dtype=np.float64)[:3], 0, 1)
    return lambda fi, p: np.broadcast_to(rgb, (len(fi), 3)).copy()


def _texture_colors(mesh, image: np.ndarray, uv: np.ndarray) -> Callable:
    """Bilinear texture lookup at the UV interpolated inside each sample's face."""
    import trimesh

    H, W = image.shape[:2]

    def fn(fi, p):
        tri = mesh.triangles[fi]
        bary = trimesh.triangles.points_to_barycentric(tri, p)
        uvp = np.einsum("nk,nkc->nc", bary, uv[mesh.faces[fi]])
        uvp = uvp - np.floor(uvp)  # wrap (GL_REPEAT)
        x = uvp[:, 0] * (W - 1)
        y = (1.0 - uvp[:, 1]) * (H - 1)  # image row 0 is v = 1
        x0 = np.clip(np.floor(x).astype(int), 0, W - 1)
        y0 = np.clip(np.floor(y).astype(int), 0, H - 1)
        x1, y1 = np.minimum(x0 + 1, W - 1), np.minimum(y0 + 1, H - 1)
        ax, ay = (x - x0)[:, None], (y - y0)[:, None]
        top = image[y0, x0] * (1 - ax) + image[y0, x1] * ax
        bot = image[y1, x0] * (1 - ax) + image[y1, x1] * ax
        return top * (1 - ay) + bot * ay

    return fn


def _mesh_color_source(mesh, urdf_rgba) -> tuple[Callable, str]:
    """Colour priority: texture > vertex/face colours > mesh material > URDF rgba > grey."""
    import trimesh

    vis = mesh.visual
    if isinstance(vis, trimesh.visual.TextureVisuals):
        mat = vis.material
        image = getattr(mat, "image", None)
        if image is None:
            image = getattr(mat, "baseColorTexture", None)
        if image is not None and vis.uv is not None and len(vis.uv) == len(mesh.vertices):
            img = np.asarray(image.convert("RGB"), dtype=np.float64) / 255.0
            return _texture_colors(mesh, img, np.asarray(vis.uv, dtype=np.float64)), "texture"
        if mat is not None:
            return _const_colors(np.asarray(mat.main_color[:3], dtype=np.float64) / 255.0), \
                "material"
    elif isinstance(vis, trimesh.visual.ColorVisuals) and vis.kind in ("vertex", "face"):
        if vis.kind == "vertex":
            vc = np.asarray(vis.vertex_colors[:, :3], dtype=np.float64) / 255.0

            def fn(fi, p):
                bary = trimesh.triangles.points_to_barycentric(mesh.triangles[fi], p)
                return np.einsum("nk,nkc->nc", bary, vc[mesh.faces[fi]])
            return fn, "vertex"
        fc = np.asarray(vis.face_colors[:, :3], dtype=np.float64) / 255.0
        return (lambda fi, p: fc[fi]), "face"
    if urdf_rgba is not None:
        return _const_colors(urdf_rgba[:3]), "urdf"
    return _const_colors(GREY), "grey"


def colored_mesh(mesh, rgba=None) -> ColoredMesh:
    """A ``trimesh.Trimesh`` with its colour source (texture > vertex/face colours > mesh
    material > ``rgba`` > grey), as :func:`load_link_meshes` makes them."""
    fn, src = _mesh_color_source(mesh, rgba)
    return ColoredMesh(mesh, fn, src)


def _load_mesh_file(path: Path):
    """trimesh meshes of a file, unprocessed (a Scene becomes its geometries in scene
    coordinates), so that every part keeps its own UVs and material."""
    import trimesh

    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as err:  # noqa: BLE001 - any loader failure is a bad asset
        raise AssetError(f"mesh file {path} could not be loaded ({type(err).__name__}: "
                         f"{err})") from None
    if isinstance(loaded, trimesh.Scene):
        meshes = [m for m in loaded.dump(concatenate=False) if isinstance(m, trimesh.Trimesh)]
    elif isinstance(loaded, trimesh.Trimesh):
        meshes = [loaded]
    else:
        meshes = []
    meshes = [m for m in meshes if len(m.faces)]
    if not meshes:
        raise AssetError(f"mesh file {path} has no triangles")
    return meshes


def load_link_meshes(model: URDFModel, links: Sequence[str] | None = None
                     ) -> dict[str, list[ColoredMesh]]:
    """Visual meshes of ``links`` (default :attr:`URDFModel.visual_links`) in link frames.

    Returns:
        link name -> its coloured meshes (metres, link frame).

    Raises:
        ConfigError: a link has no visual geometry.
        AssetError: a mesh file is missing (names the URDF and the element) or
            unreadable (names the file).
    """
    links = model.visual_links if links is None else list(links)
    out: dict[str, list[ColoredMesh]] = {}
    cache: dict[Path, list] = {}
    for name in links:
        if name not in model.visuals:
            raise ConfigError(f"link {name!r} has no visual geometry in {model.path.name}")
        items = []
        for v in model.visuals[name]:
            if v.kind == "mesh":
                path = model.mesh_path(v)
                if path not in cache:
                    cache[path] = _load_mesh_file(path)
                parts = [m.copy() for m in cache[path]]
                for m in parts:
                    m.apply_transform(np.diag([*v.scale, 1.0]))
            else:
                parts = [primitive_mesh(v, model.path.name)]
            for m in parts:
                m.apply_transform(v.origin)
                if v.kind != "mesh":
                    fn, src = _const_colors(v.rgba[:3] if v.rgba else GREY), \
                        "urdf" if v.rgba else "grey"
                else:
                    fn, src = _mesh_color_source(m, v.rgba)
                items.append(ColoredMesh(m, fn, src))
        out[name] = items
    return out


# =========================================================================== sampling
def sample_surface_blue_noise(meshes: Sequence[ColoredMesh], spacing: float,
                              rng: np.random.Generator, oversample: int = OVERSAMPLE,
                              radius: float | None = None
                              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Roughly even samples (≈ area / spacing²) over the union of ``meshes``.

    Candidates are area-uniform (``oversample / spacing²``); every pair closer
    than ``radius`` (metres, default ``0.65·spacing``) whose face normals agree
    loses the member with more such neighbours (opposite sides of thin walls do
    not thin each other).

    Args:
        meshes: the surfaces (one frame), metres.
        spacing: target sample spacing, metres.
        rng: random generator (the result is deterministic for its state).

    Returns:
        (points [n, 3] metres, normals [n, 3] unit, rgb [n, 3] in [0, 1]).
    """
    import trimesh
    from scipy.spatial import cKDTree

    radius = THIN_RADIUS * spacing if radius is None else radius
    pts, nrm, col = [], [], []
    for cm in meshes:
        area = float(cm.mesh.area)
        if not area > 0:
            continue
        n = max(1, int(round(oversample * area / spacing ** 2)))
        p, fi = trimesh.sample.sample_surface(cm.mesh, n, seed=int(rng.integers(2 ** 31)))
        pts.append(np.asarray(p))
        nrm.append(np.asarray(cm.mesh.face_normals)[fi])
        col.append(cm.colors(fi, np.asarray(p)))
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))
    p, nm, c = np.concatenate(pts), np.concatenate(nrm), np.concatenate(col)
    perm = rng.permutation(len(p))  # random tie-breaking below
    p, nm, c = p[perm], nm[perm], c[perm]
    pairs = cKDTree(p).query_pairs(radius, output_type="ndarray")
    if len(pairs):
        pairs = pairs[np.einsum("ij,ij->i", nm[pairs[:, 0]], nm[pairs[:, 1]]) > 0]
    keep = np.ones(len(p), dtype=bool)
    if len(pairs):
        degree = np.bincount(pairs.ravel(), minlength=len(p))
        # for every close pair drop the member with more close neighbours (ties: the later)
        d0, d1 = degree[pairs[:, 0]], degree[pairs[:, 1]]
        drop = np.where(d0 > d1, pairs[:, 0], pairs[:, 1])
        keep[drop] = False
    return p[keep], nm[keep], np.clip(c[keep], 0.0, 1.0)


def closed_outward(meshes: Sequence[ColoredMesh]) -> bool:
    """Whether the union of ``meshes`` (one link's) bounds solids with its face normals
    pointing out of them: after merging coincident vertices (texture seams split them)
    every edge joins two faces, the winding is consistent, and each connected part encloses a
    positive volume. Gaussians sampled on such a surface with their face normal as local z
    (:func:`gaussians_from_surface`) may be culled when that normal faces away from the
    camera: a nearer front side always hides them (see ``one_sided`` of
    :func:`~gausstac_maniskill.splat.rasterizer.rasterize`)."""
    import trimesh

    if not meshes:
        return False
    merged = trimesh.util.concatenate([cm.mesh for cm in meshes])
    merged = trimesh.Trimesh(merged.vertices, merged.faces, process=False)
    merged.merge_vertices(merge_tex=True, merge_norm=True)
    if not (merged.is_watertight and merged.is_winding_consistent):
        return False
    return all(float(part.volume) > 0.0 for part in merged.split(only_watertight=False))


def _frames_from_normals(normals: np.ndarray) -> np.ndarray:
    """[n, 3, 3] rotations whose third column (local z) is the unit normal."""
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    helper = np.where((np.abs(n[:, 0]) < 0.9)[:, None], [[1.0, 0, 0]], [[0.0, 1, 0]])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    return np.stack([t1, t2, n], axis=-1)


def gaussians_from_surface(points, normals, rgb, spacing: float, link_id: int = 0,
                           group=None) -> GaussianSet:
    """Flat disc Gaussians on surface samples.

    Each Gaussian is a disc: in-plane standard deviation ``0.9·spacing``, normal standard
    deviation ``spacing/20``, opacity ``sigmoid(4) ≈ 0.98``. With samples thinned so that no
    two with agreeing normals are closer than ``0.65·spacing`` (≈ 1 per spacing²), the
    composited opacity over a flat surface is: σ = 0.5·spacing leaves ~10 % of it below
    α = 0.9 (visible holes); σ = 0.9·spacing has its worst point at α ≈ 0.94 and 99 % of it at
    α ≥ 0.98, with a ≈ 1 σ soft fringe at silhouettes (``tests/splat/test_surface.py``
    checks a flat box for holes).

    Args:
        points: [n, 3] sample positions, metres.
        normals: [n, 3] surface normals (any length > 0); a Gaussian's local z.
        rgb: [n, 3] colours in [0, 1] (degree-0 SH).
        spacing: sample spacing, metres.
        link_id: link index for all of them.
        group: [n] labels (default -1).

    Returns:
        n Gaussians: σ = (0.9, 0.9, 0.05)·spacing, opacity ≈ 0.98.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(points)
    R = torch.as_tensor(_frames_from_normals(np.asarray(normals, dtype=np.float64)))
    quats = rotmat_to_quat(R) if n else torch.zeros(0, 4, dtype=torch.float64)
    ls = np.log(np.array([IN_PLANE_SCALE, IN_PLANE_SCALE, NORMAL_SCALE]) * spacing)
    sh = rgb_to_sh_dc(torch.as_tensor(np.array(rgb, dtype=np.float64).reshape(n, 1, 3)))
    return GaussianSet.create(points, quats, np.broadcast_to(ls, (n, 3)).copy(),
                              np.full(n, OPACITY_LOGIT), sh,
                              link_id=np.full(n, link_id), group=group)


def gaussians_from_points(points: np.ndarray, rgb: np.ndarray | None = None) -> GaussianSet:
    """Flat Gaussians on a bare point cloud: normals and spacing from 8 neighbours.

    Args:
        points: [n, 3] positions, metres (n >= 2).
        rgb: [n, 3] colours in [0, 1]; default grey.

    Returns:
        n Gaussians as :func:`gaussians_from_surface` makes them, each one's local
        z along the smallest-variance direction of its neighbourhood and the
        spacing the median neighbour distance scaled to ≈ one point per spacing².
    """
    from scipy.spatial import cKDTree

    k = min(9, len(points))
    d, j = cKDTree(points).query(points, k=k)
    nb = points[j] - points[j].mean(1, keepdims=True)
    _, V = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb))
    normals = V[:, :, 0]  # smallest-variance direction
    spacing = float(np.median(d[:, -1]) * math.sqrt(math.pi / max(k - 1, 1)))
    rgb = np.broadcast_to(GREY, points.shape) if rgb is None else rgb
    return gaussians_from_surface(points, normals, rgb, spacing)
