"""Hand Gaussians assets: built from a URDF's visual meshes, or aligned from a scan.

An asset is a folder with

* ``gaussians.ply`` — an INRIA 3DGS file (see :mod:`.gaussians`) whose Gaussians
  are stored in the **local frames of their links** (posed at run time by
  :func:`~gausstac_maniskill.splat.deform.rigid_transform`), with the extra
  integer properties ``link_id`` (index into ``links.json``'s ``link_names``) and
  ``group`` (-1 rigid, ``k >= 0`` inside pad region ``k``);
* ``links.json`` — link names in ``link_id`` order, the source URDF, Gaussians
  per link, the spacing used, pad names in ``group`` order.

Two ways to build one:

1. :func:`build_from_urdf` samples each link's visual surface (meshes or
   box/cylinder/sphere primitives) with blue-noise samples at density
   ``1 / spacing²`` and puts one flat Gaussian on every sample.
2. :func:`build_from_scan` aligns a point cloud or Gaussian scene in an
   arbitrary frame to the URDF hand at a reference pose (centroids + principal
   axes matched in every proper order/sign flip, then trimmed ICP, lowest
   residual wins), gives every point the link of the nearest posed link surface
   and moves it into that link's frame (means, rotations and SH).

Splat shape (path 1). Samples come from area-uniform candidates at 4/spacing²
thinned so that no two samples with agreeing normals are closer than
``0.65·spacing`` (this lands at ≈ 1 sample per spacing², i.e. ``N ≈ area /
spacing²``). Each Gaussian is a disc: in-plane standard deviation
``0.9·spacing``, normal standard deviation ``spacing/20``, opacity
``sigmoid(4) ≈ 0.98``. The in-plane factor was chosen by measuring the
composited opacity of such a sample set over a flat surface: with σ = 0.5·s
(≈ half the spacing) ~10 % of the surface stays below α = 0.9 (visible holes);
with σ = 0.9·s the worst point has α ≈ 0.94 and 99 % of it α ≥ 0.98, at the
price of a ≈ 1 σ soft fringe at silhouettes. ``tests/splat/test_build.py``
renders a flat box built this way and checks for holes.

Units: metres throughout. The URDF root link is the world frame of the
reference pose.
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np
import torch

from ..errors import AssetError, ConfigError
from ..urdf import default_hand_urdf, rpy_matrix
from .gaussians import GaussianSet, load_ply, rgb_to_sh_dc, rotmat_to_quat, save_ply

__all__ = [
    "DEFAULT_SPACING",
    "IN_PLANE_SCALE",
    "NORMAL_SCALE",
    "OPACITY_LOGIT",
    "URDFJoint",
    "URDFVisual",
    "URDFModel",
    "ColoredMesh",
    "HandAsset",
    "ScanAlignment",
    "default_urdf",
    "parse_urdf",
    "load_link_meshes",
    "sample_surface_blue_noise",
    "gaussians_from_surface",
    "build_from_urdf",
    "sample_posed_hand",
    "load_scan",
    "align_point_clouds",
    "assign_links",
    "build_from_scan",
    "rotate_sh",
    "save_asset",
    "main",
]

DEFAULT_SPACING = 1.5e-3  #: target sample spacing, metres
IN_PLANE_SCALE = 0.9      #: in-plane σ / spacing (see the module docstring)
NORMAL_SCALE = 1.0 / 20   #: normal σ / spacing
OPACITY_LOGIT = 4.0       #: opacity sigmoid(4) ≈ 0.982
THIN_RADIUS = 0.65        #: blue-noise exclusion radius / spacing
OVERSAMPLE = 4            #: candidates per target sample
GREY = (0.5, 0.5, 0.5)

PadRegions = Mapping[str, Callable[[np.ndarray], np.ndarray]]


# =========================================================================== URDF
def default_urdf() -> Path:
    """ManiSkill's ``allegro_hand_right.urdf`` (the ``.obj`` visual meshes)."""
    return Path(default_hand_urdf())


def _axis_angle_matrix(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


@dataclass
class URDFVisual:
    """One ``<visual>`` of a link.

    Attributes:
        origin: [4, 4] visual -> link transform.
        kind: ``"mesh" | "box" | "cylinder" | "sphere"``.
        filename: resolved mesh path (``kind == "mesh"``), else None.
        scale: [3] mesh scale.
        size: box size [3], or (radius, length) / (radius,) for cylinder / sphere.
        rgba: URDF ``<material><color rgba>`` or None.
    """

    origin: np.ndarray
    kind: str
    filename: Path | None = None
    scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    size: tuple = ()
    rgba: tuple | None = None


@dataclass
class URDFJoint:
    """A URDF joint: child pose = parent pose · origin · motion(q) about/along ``axis``."""

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray


@dataclass
class URDFModel:
    """The kinematic tree and visuals of a URDF (what this module needs of it).

    Attributes:
        path: the URDF file.
        name: ``<robot name>``.
        links: every link name, in file order.
        visuals: link name -> its visuals (links without visuals are absent).
        joints: every joint, in file order.
    """

    path: Path
    name: str
    links: list[str]
    visuals: dict[str, list[URDFVisual]]
    joints: list[URDFJoint]

    @property
    def visual_links(self) -> list[str]:
        """Links with at least one visual, in URDF (file) order: the default link order."""
        return [n for n in self.links if self.visuals.get(n)]

    @property
    def joint_names(self) -> list[str]:
        """Names of the movable (revolute, continuous, prismatic) joints, file order."""
        return [j.name for j in self.joints if j.type in ("revolute", "continuous", "prismatic")]

    def forward_kinematics(self, q=None) -> dict[str, np.ndarray]:
        """World [4, 4] pose of every link, the root link(s) at the identity.

        Args:
            q: joint positions (radians / metres): ``None`` (all zero), a mapping
                joint name -> value (missing joints are 0), or a sequence in
                :attr:`joint_names` order.
        """
        names = self.joint_names
        if q is None:
            qmap = {}
        elif isinstance(q, Mapping):
            unknown = [k for k in q if k not in names]
            if unknown:
                raise ConfigError(f"unknown joint {unknown[0]!r} in joint positions "
                                  f"(movable joints: {', '.join(names)})")
            qmap = {k: float(v) for k, v in q.items()}
        else:
            vals = np.asarray(q, dtype=np.float64).reshape(-1)
            if vals.shape[0] != len(names):
                raise ConfigError(f"joint positions have {vals.shape[0]} values, the URDF "
                                  f"{self.path.name} has {len(names)} movable joints")
            qmap = dict(zip(names, vals.tolist()))
        by_child = {}
        for j in self.joints:
            if j.child in by_child:
                raise AssetError(f"{self.path.name}: link '{j.child}' is the child of two "
                                 f"joints ('{by_child[j.child].name}', '{j.name}')")
            by_child[j.child] = j
        poses: dict[str, np.ndarray] = {}

        def pose_of(link: str, depth: int = 0) -> np.ndarray:
            if link in poses:
                return poses[link]
            if depth > len(self.links):
                raise AssetError(f"{self.path.name}: the joints form a cycle through "
                                 f"link '{link}'")
            j = by_child.get(link)
            if j is None:
                T = np.eye(4)
            else:
                motion = np.eye(4)
                v = qmap.get(j.name, 0.0)
                if j.type in ("revolute", "continuous"):
                    motion[:3, :3] = _axis_angle_matrix(j.axis, v)
                elif j.type == "prismatic":
                    motion[:3, 3] = j.axis / np.linalg.norm(j.axis) * v
                T = pose_of(j.parent, depth + 1) @ j.origin @ motion
            poses[link] = T
            return T

        for link in self.links:
            pose_of(link)
        return poses

    def link_poses(self, names: Sequence[str], q=None) -> torch.Tensor:
        """[L, 4, 4] float64 world poses of ``names`` at joint positions ``q``."""
        fk = self.forward_kinematics(q)
        missing = [n for n in names if n not in fk]
        if missing:
            raise ConfigError(f"unknown link {missing[0]!r} for URDF {self.path.name}")
        return torch.as_tensor(np.stack([fk[n] for n in names]), dtype=torch.float64)


def _floats(elem: ET.Element, attr: str, n: int, default, where: str, file: str) -> np.ndarray:
    text = elem.get(attr)
    if text is None:
        if default is None:
            raise AssetError(f"{file}: {where} has no '{attr}' attribute")
        return np.asarray(default, dtype=np.float64)
    try:
        vals = np.array([float(v) for v in text.split()], dtype=np.float64)
    except ValueError:
        raise AssetError(f"{file}: {where} attribute {attr}={text!r} is not {n} numbers") from None
    if vals.shape[0] == 1 and n == 3 and attr == "scale":
        vals = np.repeat(vals, 3)
    if vals.shape[0] != n or not np.all(np.isfinite(vals)):
        raise AssetError(f"{file}: {where} attribute {attr}={text!r} is not {n} finite numbers")
    return vals


def _origin(parent: ET.Element, where: str, file: str) -> np.ndarray:
    T = np.eye(4)
    o = parent.find("origin")
    if o is not None:
        T[:3, :3] = rpy_matrix(_floats(o, "rpy", 3, (0, 0, 0), f"{where} <origin>", file))
        T[:3, 3] = _floats(o, "xyz", 3, (0, 0, 0), f"{where} <origin>", file)
    return T


def _material_rgba(mat: ET.Element | None, named: dict, where: str, file: str):
    if mat is None:
        return None
    color = mat.find("color")
    if color is not None:
        return tuple(_floats(color, "rgba", 4, None, f"{where} <material><color>", file))
    return named.get(mat.get("name"))


def parse_urdf(path: str | os.PathLike) -> URDFModel:
    """Parse links, joints and visuals of a URDF (mesh paths relative to its folder).

    ``package://`` mesh URIs are resolved by dropping the package name and
    trying the URDF folder and its parents.

    Raises:
        AssetError: the file is missing or not XML (names the file), or an
            element is malformed (names the link/joint and the element).
    """
    path = Path(path)
    file = path.name
    if not path.is_file():
        raise AssetError(f"URDF file not found: {path}")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as err:
        raise AssetError(f"{path}: malformed URDF XML ({err})") from None
    if root.tag != "robot":
        raise AssetError(f"{path}: root element is <{root.tag}>, expected <robot>")
    named = {}
    for mat in root.findall("material"):
        rgba = _material_rgba(mat, {}, f"<material name={mat.get('name')!r}>", file)
        if rgba is not None:
            named[mat.get("name")] = rgba
    links, visuals = [], {}
    for i, link in enumerate(root.findall("link")):
        name = link.get("name")
        if not name:
            raise AssetError(f"{file}: <link> number {i} has no 'name' attribute")
        if name in visuals or name in links:
            raise AssetError(f"{file}: <link name={name!r}> is defined twice")
        links.append(name)
        vis_list = []
        for k, vis in enumerate(link.findall("visual")):
            where = f"<link name={name!r}> <visual> {k}"
            geom = vis.find("geometry")
            if geom is None or len(geom) == 0:
                raise AssetError(f"{file}: {where} has no <geometry>")
            g = geom[0]
            rgba = _material_rgba(vis.find("material"), named, where, file)
            origin = _origin(vis, where, file)
            if g.tag == "mesh":
                fname = g.get("filename")
                if not fname:
                    raise AssetError(f"{file}: {where} <mesh> has no 'filename' attribute")
                vis_list.append(URDFVisual(origin, "mesh", _resolve_mesh(path, fname),
                                           _floats(g, "scale", 3, (1, 1, 1), f"{where} <mesh>",
                                                   file), rgba=rgba))
            elif g.tag == "box":
                vis_list.append(URDFVisual(origin, "box", size=tuple(
                    _floats(g, "size", 3, None, f"{where} <box>", file)), rgba=rgba))
            elif g.tag == "cylinder":
                r = _floats(g, "radius", 1, None, f"{where} <cylinder>", file)[0]
                length = _floats(g, "length", 1, None, f"{where} <cylinder>", file)[0]
                vis_list.append(URDFVisual(origin, "cylinder", size=(r, length), rgba=rgba))
            elif g.tag == "sphere":
                r = _floats(g, "radius", 1, None, f"{where} <sphere>", file)[0]
                vis_list.append(URDFVisual(origin, "sphere", size=(r,), rgba=rgba))
            else:
                raise AssetError(f"{file}: {where} has unsupported geometry <{g.tag}>")
        if vis_list:
            visuals[name] = vis_list
    link_set = set(links)
    joints = []
    for i, jt in enumerate(root.findall("joint")):
        name = jt.get("name") or f"#{i}"
        where = f"<joint name={name!r}>"
        jtype = jt.get("type")
        if jtype not in ("revolute", "continuous", "prismatic", "fixed", "floating", "planar"):
            raise AssetError(f"{file}: {where} has type {jtype!r}, expected revolute, "
                             "continuous, prismatic, fixed, floating or planar")
        ends = {}
        for tag in ("parent", "child"):
            e = jt.find(tag)
            if e is None or not e.get("link"):
                raise AssetError(f"{file}: {where} has no <{tag} link=...>")
            if e.get("link") not in link_set:
                raise AssetError(f"{file}: {where} <{tag}> names unknown link {e.get('link')!r}")
            ends[tag] = e.get("link")
        axis_el = jt.find("axis")
        axis = (np.array([1.0, 0, 0]) if axis_el is None
                else _floats(axis_el, "xyz", 3, None, f"{where} <axis>", file))
        if np.linalg.norm(axis) < 1e-12:
            raise AssetError(f"{file}: {where} <axis> is zero")
        joints.append(URDFJoint(name, jtype, ends["parent"], ends["child"],
                                _origin(jt, where, file), axis))
    return URDFModel(path, root.get("name", path.stem), links, visuals, joints)


def _resolve_mesh(urdf: Path, fname: str) -> Path:
    if fname.startswith("file://"):
        return Path(fname[7:])
    if fname.startswith("package://"):
        rel = Path(*Path(fname[len("package://"):]).parts[1:])
        for base in [urdf.parent, *urdf.parent.parents]:
            if (base / rel).is_file():
                return base / rel
        return urdf.parent / rel
    p = Path(fname)
    return p if p.is_absolute() else urdf.parent / p


# =========================================================================== meshes
@dataclass
class ColoredMesh:
    """A triangle mesh in its link's frame with a colour source.

    ``colors(face_index, points)`` -> [n, 3] RGB in [0, 1] at surface points.
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


def _load_mesh_file(path: Path):
    """trimesh meshes of a file (a Scene becomes its geometries in scene coordinates)."""
    import trimesh

    if not path.is_file():
        raise AssetError(f"mesh file not found: {path}")
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

    Raises AssetError naming the mesh file when it is missing or unreadable.
    """
    import trimesh

    links = model.visual_links if links is None else list(links)
    out: dict[str, list[ColoredMesh]] = {}
    cache: dict[Path, list] = {}
    for name in links:
        if name not in model.visuals:
            raise ConfigError(f"link {name!r} has no visual geometry in {model.path.name}")
        items = []
        for v in model.visuals[name]:
            if v.kind == "mesh":
                if v.filename not in cache:
                    cache[v.filename] = _load_mesh_file(v.filename)
                parts = [m.copy() for m in cache[v.filename]]
                for m in parts:
                    m.apply_transform(np.diag([*v.scale, 1.0]))
            elif v.kind == "box":
                parts = [trimesh.creation.box(extents=v.size)]
            elif v.kind == "cylinder":
                parts = [trimesh.creation.cylinder(radius=v.size[0], height=v.size[1],
                                                   sections=48)]
            else:
                parts = [trimesh.creation.icosphere(subdivisions=3, radius=v.size[0])]
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
    than ``radius`` (default ``0.65·spacing``) whose face normals agree loses
    the member with more such neighbours (opposite sides of thin walls do not
    thin each other).

    Returns:
        (points [n, 3], normals [n, 3] unit, rgb [n, 3] in [0, 1]).
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
    """Flat disc Gaussians on surface samples (shape constants in the module docstring).

    Args:
        points: [n, 3] sample positions; normals: [n, 3]; rgb: [n, 3] in [0, 1].
        spacing: sample spacing, metres.
        link_id: link index for all of them; group: [n] labels (default -1).
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


def _pad_groups(pad_regions: PadRegions | None, link: str, local_points: np.ndarray,
                pad_names: list[str]) -> np.ndarray:
    group = np.full(len(local_points), -1, dtype=np.int64)
    if pad_regions and link in pad_regions:
        mask = np.asarray(pad_regions[link](local_points), dtype=bool).reshape(-1)
        if mask.shape[0] != len(local_points):
            raise ConfigError(f"pad_regions[{link!r}] returned {mask.shape[0]} values for "
                              f"{len(local_points)} points")
        group[mask] = pad_names.index(link)
    return group


def _check_pads(pad_regions: PadRegions | None, links: Sequence[str]) -> list[str]:
    if not pad_regions:
        return []
    for name, fn in pad_regions.items():
        if name not in links:
            raise ConfigError(f"pad_regions names link {name!r}, which has no Gaussians "
                              f"(links: {', '.join(links)})")
        if not callable(fn):
            raise ConfigError(f"pad_regions[{name!r}] must be callable(points_local) -> mask")
    return list(pad_regions)


@dataclass
class HandAsset:
    """Hand Gaussians in link frames, plus what ``links.json`` records.

    Attributes:
        gaussians: link-local Gaussians with ``link_id`` / ``group`` labels.
        link_names: link names in ``link_id`` order.
        pad_names: link names of the pads in ``group`` order.
        meta: extra ``links.json`` fields (source, spacing, ...).
    """

    gaussians: GaussianSet
    link_names: list[str]
    pad_names: list[str] = field(default_factory=list)
    meta: dict = field(default_factory=dict)

    def counts(self) -> dict[str, int]:
        """Gaussians per link."""
        c = torch.bincount(self.gaussians.link_id, minlength=len(self.link_names))
        return {n: int(c[i]) for i, n in enumerate(self.link_names)}


def _progress(iterable, enabled: bool, desc: str):
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, disable=not enabled, leave=False)


def build_from_urdf(urdf: str | os.PathLike | None = None, spacing: float = DEFAULT_SPACING,
                    links: Sequence[str] | None = None, pad_regions: PadRegions | None = None,
                    seed: int = 0, progress: bool = True) -> HandAsset:
    """Gaussians on every link's visual surface, in link frames.

    Args:
        urdf: URDF file; default ManiSkill's Allegro right hand.
        spacing: target sample spacing, metres (≈ area / spacing² Gaussians).
        links: links to build (default every link with a visual, URDF order);
            their order is the ``link_id`` order.
        pad_regions: link name -> ``fn(points_local [n, 3]) -> bool mask [n]``;
            Gaussians of that link where the mask is true get ``group`` = the
            index of the link in ``pad_regions`` (insertion order), others -1.
        seed: sampling seed (the result is deterministic for a seed).
        progress: show a tqdm bar over links.
    """
    if not (isinstance(spacing, (int, float)) and 0 < spacing < 1 and math.isfinite(spacing)):
        raise ConfigError(f"spacing={spacing!r} must be a positive length in metres (< 1)")
    model = parse_urdf(default_urdf() if urdf is None else urdf)
    links = model.visual_links if links is None else list(links)
    if not links:
        raise AssetError(f"{model.path.name}: no link has visual geometry")
    pad_names = _check_pads(pad_regions, links)
    rng = np.random.default_rng(seed)
    meshes = load_link_meshes(model, links)
    sets, sources = [], {}
    for i, name in enumerate(_progress(links, progress, "gaussians per link")):
        p, nm, c = sample_surface_blue_noise(meshes[name], spacing, rng)
        group = _pad_groups(pad_regions, name, p, pad_names)
        sets.append(gaussians_from_surface(p, nm, c, spacing, link_id=i, group=group))
        sources[name] = sorted({m.source for m in meshes[name]})
    meta = {"source": "urdf", "spacing": float(spacing), "seed": int(seed),
            "colour_sources": sources,
            "splat": {"in_plane_sigma": IN_PLANE_SCALE * spacing,
                      "normal_sigma": NORMAL_SCALE * spacing,
                      "opacity_logit": OPACITY_LOGIT}}
    return HandAsset(GaussianSet.cat(sets), links, pad_names,
                     {"urdf": model.path.name, "robot": model.name, **meta})


# =========================================================================== scans
def sample_posed_hand(model: URDFModel, spacing: float, q=None,
                      links: Sequence[str] | None = None, seed: int = 0,
                      meshes: dict | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Area-uniform samples of the hand's visual surface in the world at joints ``q``.

    Returns:
        (points [n, 3], normals [n, 3], link index [n] into ``links``).
    """
    import trimesh

    links = model.visual_links if links is None else list(links)
    meshes = load_link_meshes(model, links) if meshes is None else meshes
    fk = model.forward_kinematics(q)
    rng = np.random.default_rng(seed)
    P, N, L = [], [], []
    for i, name in enumerate(links):
        T = fk[name]
        for cm in meshes[name]:
            n = max(1, int(round(cm.mesh.area / spacing ** 2)))
            p, fi = trimesh.sample.sample_surface(cm.mesh, n, seed=int(rng.integers(2 ** 31)))
            P.append(p @ T[:3, :3].T + T[:3, 3])
            N.append(np.asarray(cm.mesh.face_normals)[fi] @ T[:3, :3].T)
            L.append(np.full(n, i))
    return np.concatenate(P), np.concatenate(N), np.concatenate(L)


def load_scan(path: str | os.PathLike) -> tuple[np.ndarray, GaussianSet | None, np.ndarray | None]:
    """Read a scan: an INRIA Gaussian ``.ply``, a point ``.ply``, ``.xyz`` or ``.npy``.

    Returns:
        (points [n, 3] float64, the GaussianSet if the file holds Gaussians else
        None, rgb [n, 3] in [0, 1] if the file has colours else None).

    ``.xyz``: whitespace-separated rows ``x y z [r g b]`` (colours 0..1 or 0..255).
    ``.npy``: an [n, 3] or [n, 6] array, same meaning.
    """
    path = Path(path)
    if not path.is_file():
        raise AssetError(f"scan file not found: {path}")
    ext = path.suffix.lower()
    rgb = None
    if ext == ".ply":
        from plyfile import PlyData

        try:
            ply = PlyData.read(str(path))
        except Exception as err:  # noqa: BLE001
            raise AssetError(f"{path.name}: unreadable .ply ({type(err).__name__}: {err})") \
                from None
        names = [e.name for e in ply.elements]
        if "vertex" not in names:
            raise AssetError(f"{path.name}: element 'vertex' missing")
        props = {p.name for p in ply["vertex"].properties}
        if {"f_dc_0", "opacity", "scale_0", "rot_0"} <= props:
            g = load_ply(path)
            return g.means.double().numpy(), g, None
        for f in ("x", "y", "z"):
            if f not in props:
                raise AssetError(f"{path.name}: vertex property '{f}' missing")
        v = ply["vertex"]
        arr = np.stack([np.asarray(v[f], dtype=np.float64) for f in ("x", "y", "z")], 1)
        if {"red", "green", "blue"} <= props:
            rgb = np.stack([np.asarray(v[f], dtype=np.float64) for f in ("red", "green", "blue")],
                           1)
            rgb = rgb / 255.0 if rgb.max() > 1.0 else rgb
    elif ext in (".xyz", ".txt", ".npy"):
        try:
            arr = np.load(path) if ext == ".npy" else np.loadtxt(path, ndmin=2)
        except Exception as err:  # noqa: BLE001
            raise AssetError(f"{path.name}: unreadable point file ({type(err).__name__}: "
                             f"{err})") from None
        arr = np.asarray(arr, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[1] not in (3, 6):
            raise AssetError(f"{path.name}: points have shape {list(arr.shape)}, expected "
                             "[n, 3] (x y z) or [n, 6] (x y z r g b)")
        if arr.shape[1] == 6:
            rgb = arr[:, 3:]
            rgb = rgb / 255.0 if rgb.max() > 1.0 else rgb
        arr = arr[:, :3]
    else:
        raise AssetError(f"{path.name}: unknown scan format {ext!r} (use .ply, .xyz or .npy)")
    if len(arr) < 10:
        raise AssetError(f"{path.name}: only {len(arr)} points, need at least 10")
    if not np.all(np.isfinite(arr)):
        raise AssetError(f"{path.name}: points contain NaN or inf")
    return arr, None, None if rgb is None else np.clip(rgb, 0, 1)


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """4x4 rigid T minimising Σ |T a - b|² (rows are corresponding points)."""
    ca, cb = a.mean(0), b.mean(0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, cb - R @ ca
    return T


def _apply(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ T[:3, :3].T + T[:3, 3]


def _icp(src: np.ndarray, tree, dst: np.ndarray, dst_n: np.ndarray, T: np.ndarray,
         iters_p2p: int, iters_p2l: int, trim: float) -> tuple[np.ndarray, float]:
    """Trimmed ICP: point-to-point (Kabsch) iterations, then point-to-plane (Gauss-Newton).

    Returns (T, RMS nearest distance over the kept ``trim`` fraction).
    """
    workers = -1 if len(src) > 5000 else 1  # threads only pay off for big queries

    def matches(T):
        p = _apply(T, src)
        d, j = tree.query(p, workers=workers)
        keep = d <= np.quantile(d, trim)
        return p, d, j, keep

    for _ in range(iters_p2p):
        p, d, j, keep = matches(T)
        dT = _kabsch(p[keep], dst[j[keep]])
        T = dT @ T
        if np.abs(dT[:3, :3] - np.eye(3)).max() < 1e-6 and np.abs(dT[:3, 3]).max() < 1e-7:
            break
    for _ in range(iters_p2l):
        p, d, j, keep = matches(T)
        p, q, n = p[keep], dst[j[keep]], dst_n[j[keep]]
        # r = (p - q)·n ; linearised in (ω, t): r + (p × n)·ω + n·t
        A = np.concatenate([np.cross(p, n), n], axis=1)
        r = np.einsum("ij,ij->i", p - q, n)
        x = np.linalg.lstsq(A.T @ A + 1e-12 * np.eye(6), -A.T @ r, rcond=None)[0]
        w, t = x[:3], x[3:]
        dT = np.eye(4)
        ang = np.linalg.norm(w)
        if ang > 0:
            dT[:3, :3] = _axis_angle_matrix(w, ang)
        dT[:3, 3] = t
        T = dT @ T
        if ang < 1e-7 and np.linalg.norm(t) < 1e-8:
            break
    _, d, _, keep = matches(T)
    return T, float(np.sqrt(np.mean(d[keep] ** 2)))


@dataclass
class ScanAlignment:
    """Result of :func:`align_point_clouds`.

    Attributes:
        transform: [4, 4] scan frame -> hand (URDF root) frame.
        rms: trimmed RMS nearest-neighbour distance after alignment, metres.
        candidates: (initialisation name, rms) of every start tried.
    """

    transform: np.ndarray
    rms: float
    candidates: list


def align_point_clouds(scan: np.ndarray, reference: np.ndarray, reference_normals: np.ndarray,
                       init="pca", trim: float = 0.9, max_points: int = 20000,
                       refine: int = 3, seed: int = 0) -> ScanAlignment:
    """Rigid transform taking ``scan`` onto ``reference`` (oriented samples of the hand).

    Args:
        scan: [n, 3] points in an arbitrary frame.
        reference: [m, 3] dense samples of the target surface; reference_normals [m, 3].
        init: ``"pca"`` — centroids matched, principal axes matched in each of
            the 24 proper orders/sign flips (a partial scan can reorder them);
            ``"identity"`` — start where the scan is (and also from the
            centroid-matched identity); or a [4, 4] guess of scan -> hand.
            Every start runs coarse point-to-point ICP on a subset; the
            ``refine`` best continue with point-to-plane ICP and the lowest
            trimmed RMS wins.
        trim: fraction of closest correspondences used per iteration (robust
            to partial overlap and stray points).
        max_points: scan points used by ICP (random subset).
        refine: how many of the best coarse results are refined to convergence.
    """
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    src = scan if len(scan) <= max_points else scan[rng.choice(len(scan), max_points, False)]
    cs, cr = src.mean(0), reference.mean(0)
    starts = []
    if isinstance(init, str) and init == "pca":
        def axes(p, c):
            w, V = np.linalg.eigh(np.cov((p - c).T))
            return V[:, ::-1]  # largest first
        Vs, Vr = axes(src, cs), axes(reference, cr)
        # matched axes first (a full scan), then the other axis orders (a partial scan
        # can reorder the principal axes); each with the sign flips giving det = +1
        for perm in itertools.permutations(range(3)):
            for signs in itertools.product((1, -1), repeat=3):
                R = Vr[:, list(perm)] @ np.diag(signs) @ Vs.T
                if np.linalg.det(R) < 0:
                    continue
                T = np.eye(4)
                T[:3, :3], T[:3, 3] = R, cr - R @ cs
                starts.append((f"pca{perm}{signs}", T))
    elif isinstance(init, str) and init == "identity":
        T = np.eye(4)
        starts.append(("identity", T.copy()))
        T[:3, 3] = cr - cs
        starts.append(("centroid", T))
    else:
        from ..transforms import as_pose_matrix

        starts.append(("guess", as_pose_matrix(init, "scan frame guess")))
    # coarse: every start on a small subset (far-off starts make k-d queries slow)
    sub = src[rng.choice(len(src), min(len(src), 1500), False)]
    ref_idx = rng.choice(len(reference), min(len(reference), 10000), False)
    coarse_tree = cKDTree(reference[ref_idx])
    results = []
    for name, T0 in starts:
        T, rms = _icp(sub, coarse_tree, reference[ref_idx], reference_normals[ref_idx], T0,
                      30, 0, trim)
        results.append((rms, name, T))
    results.sort(key=lambda r: r[0])
    # the best few go on (small subset, point-to-plane); the lowest residual wins
    tree = cKDTree(reference)
    best = None
    for _, name, T in results[:refine]:
        T, rms = _icp(sub, tree, reference, reference_normals, T, 10, 20, trim)
        if best is None or rms < best[0]:
            best = (rms, T)
    # fine: the winner with all (up to max_points) scan points, to convergence
    T, rms = _icp(src, tree, reference, reference_normals, best[1], 2, 40, trim)
    return ScanAlignment(T, rms, [(n, float(r)) for r, n, _ in results])


def _sh_basis(d: np.ndarray, degree: int) -> np.ndarray:
    """[m, K] real SH basis in the rasterizer's convention at unit directions d [m, 3]."""
    from .rasterizer import SH_C0, SH_C1, SH_C2, SH_C3

    x, y, z = d.T
    b = [np.full_like(x, SH_C0)]
    if degree >= 1:
        b += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        b += [SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2 * zz - xx - yy),
              SH_C2[3] * x * z, SH_C2[4] * (xx - yy)]
    if degree >= 3:
        b += [SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * x * y * z,
              SH_C3[2] * y * (4 * zz - xx - yy), SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
              SH_C3[4] * x * (4 * zz - xx - yy), SH_C3[5] * z * (xx - yy),
              SH_C3[6] * x * (xx - 3 * yy)]
    return np.stack(b, axis=-1)


def rotate_sh(sh: torch.Tensor, R: np.ndarray) -> torch.Tensor:
    """SH coefficients [n, K, 3] re-expressed in a rotated frame.

    ``R`` [3, 3] maps new-frame directions to old-frame ones (d_old = R d_new):
    the result c' satisfies Σ c'_k Y_k(d) = Σ c_k Y_k(R d) for every d. Each
    band is closed under rotation, so the K×K matrix is solved exactly by least
    squares on random directions.
    """
    K = sh.shape[1]
    if K == 1:
        return sh.clone()
    degree = int(round(math.sqrt(K))) - 1
    d = np.random.default_rng(0).normal(size=(64, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    B, BR = _sh_basis(d, degree), _sh_basis(d @ np.asarray(R).T, degree)
    M = np.linalg.lstsq(B, BR, rcond=None)[0]  # B M = BR  ->  c' = M c
    return torch.einsum("kj,njc->nkc", torch.as_tensor(M, dtype=sh.dtype), sh)


def assign_links(points: np.ndarray, ref_points: np.ndarray, ref_links: np.ndarray,
                 meshes: Mapping[str, Sequence[ColoredMesh]], links: Sequence[str],
                 poses: Mapping[str, np.ndarray], k: int = 8
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Link of the nearest posed link surface for each world point.

    The ``k`` nearest surface samples propose candidate links; where they
    disagree (near joints, where link meshes meet or overlap) the exact
    point-to-triangle distance to each candidate link's posed mesh decides.

    Returns:
        (link index [n] into ``links``, distance to the nearest sample [n], metres).
    """
    import trimesh
    from scipy.spatial import cKDTree

    d, j = cKDTree(ref_points).query(points, k=min(k, len(ref_points)), workers=-1)
    d, j = d.reshape(len(points), -1), j.reshape(len(points), -1)
    cand = ref_links[j]
    label = cand[:, 0].astype(np.int64)
    amb = np.nonzero((cand != cand[:, :1]).any(axis=1))[0]
    if len(amb):
        best = np.full(len(amb), np.inf)
        for i in np.unique(cand[amb]):
            rows = np.nonzero((cand[amb] == i).any(axis=1))[0]
            m = trimesh.util.concatenate([c.mesh for c in meshes[links[i]]])
            m.apply_transform(poses[links[i]])
            _, dist, _ = trimesh.proximity.closest_point(m, points[amb[rows]])
            better = dist < best[rows]
            best[rows[better]] = dist[better]
            label[amb[rows[better]]] = i
    return label, d[:, 0]


def _gaussians_for_points(points: np.ndarray, rgb: np.ndarray | None) -> GaussianSet:
    """Flat Gaussians on a bare point cloud: normals and spacing from 8 neighbours."""
    from scipy.spatial import cKDTree

    k = min(9, len(points))
    d, j = cKDTree(points).query(points, k=k)
    nb = points[j] - points[j].mean(1, keepdims=True)
    _, V = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb))
    normals = V[:, :, 0]  # smallest-variance direction
    spacing = float(np.median(d[:, -1]) * math.sqrt(math.pi / max(k - 1, 1)))
    rgb = np.broadcast_to(GREY, points.shape) if rgb is None else rgb
    return gaussians_from_surface(points, normals, rgb, spacing)


def build_from_scan(scan, urdf: str | os.PathLike | None = None, joint_positions=None,
                    init="pca", links: Sequence[str] | None = None,
                    pad_regions: PadRegions | None = None, max_distance: float | None = 0.01,
                    reference_spacing: float = 1e-3, seed: int = 0,
                    progress: bool = True) -> tuple[HandAsset, ScanAlignment, np.ndarray]:
    """Align a scan to the URDF hand at a reference pose and split it into links.

    Args:
        scan: a file (see :func:`load_scan`), a GaussianSet, or [n, 3] points,
            in an arbitrary frame, of the hand at the reference pose.
        urdf: URDF file; default ManiSkill's Allegro right hand.
        joint_positions: the reference pose (see :meth:`URDFModel.forward_kinematics`);
            default all joints at 0.
        init: initial alignment, see :func:`align_point_clouds`.
        links: links to assign to (default all with visuals); ``link_id`` order.
        pad_regions: as :func:`build_from_urdf`, evaluated on link-local means.
        max_distance: drop scan Gaussians farther than this (metres) from the
            aligned hand surface (background, table); None keeps all.
        reference_spacing: spacing of the hand surface samples used for ICP and
            link assignment, metres.

    Returns:
        (asset with link-local Gaussians, the alignment, link index per
        *input* point (-1 where dropped)).
    """
    if isinstance(scan, GaussianSet):
        g = scan.to("cpu")
        points = g.means.double().numpy()
    elif isinstance(scan, (str, os.PathLike)):
        points, g, rgb = load_scan(scan)
        if g is None:
            g = _gaussians_for_points(points, rgb)
    else:
        points = np.asarray(scan, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3 or len(points) < 10:
            raise ConfigError(f"scan points have shape {list(points.shape)}, expected [n>=10, 3]")
        g = _gaussians_for_points(points, None)
    model = parse_urdf(default_urdf() if urdf is None else urdf)
    links = model.visual_links if links is None else list(links)
    pad_names = _check_pads(pad_regions, links)
    meshes = load_link_meshes(model, links)
    ref_p, ref_n, ref_l = sample_posed_hand(model, reference_spacing, joint_positions, links,
                                            seed=seed, meshes=meshes)
    align = align_point_clouds(points, ref_p, ref_n, init=init, seed=seed)
    from scipy.spatial import cKDTree

    world = _apply(align.transform, points)
    fk = model.forward_kinematics(joint_positions)
    label, dist = assign_links(world, ref_p, ref_l, meshes, links, fk)
    if max_distance is not None:
        label[dist > max_distance] = -1
    R_align = align.transform[:3, :3]
    sets = []
    for i, name in enumerate(_progress(links, progress, "assign scan to links")):
        sel = np.nonzero(label == i)[0]
        if len(sel) == 0:
            continue
        Tl = fk[name]
        local = (world[sel] - Tl[:3, 3]) @ Tl[:3, :3]  # R_lᵀ (x - t_l)
        Q = Tl[:3, :3].T @ R_align  # scan axes -> link axes
        sub = g[torch.as_tensor(sel)]
        quats = rotmat_to_quat(torch.as_tensor(Q) @ _quat_rotmat64(sub.quats))
        sh = rotate_sh(sub.sh, R_align.T @ Tl[:3, :3])
        group = _pad_groups(pad_regions, name, local, pad_names)
        sets.append(GaussianSet.create(local, quats, sub.log_scales, sub.opacity_logits, sh,
                                       link_id=np.full(len(sel), i), group=group))
    if not sets:
        raise AssetError("no scan point lies within max_distance of the aligned hand")
    meta = {"urdf": model.path.name, "robot": model.name, "source": "scan",
            "scan": str(scan) if isinstance(scan, (str, os.PathLike)) else None,
            "scan_to_hand": align.transform.tolist(), "icp_rms": align.rms,
            "reference_joint_positions": _qdict(model, joint_positions),
            "dropped": int((label < 0).sum()), "seed": int(seed)}
    return HandAsset(GaussianSet.cat(sets), links, pad_names, meta), align, label


def _quat_rotmat64(q: torch.Tensor) -> torch.Tensor:
    from .gaussians import quat_to_rotmat

    return quat_to_rotmat(q.double())


def _qdict(model: URDFModel, q) -> dict:
    if q is None:
        return {n: 0.0 for n in model.joint_names}
    if isinstance(q, Mapping):
        return {n: float(q.get(n, 0.0)) for n in model.joint_names}
    return dict(zip(model.joint_names, np.asarray(q, dtype=float).reshape(-1).tolist()))


# =========================================================================== output
def save_asset(out_dir: str | os.PathLike, asset: HandAsset) -> tuple[Path, Path]:
    """Write ``gaussians.ply`` and ``links.json`` into ``out_dir`` (created)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ply, js = out / "gaussians.ply", out / "links.json"
    save_ply(ply, asset.gaussians, labels=True)
    info = {"format": "gausstac-hand-gaussians/1",
            "link_names": list(asset.link_names),
            "counts": asset.counts(),
            "num_gaussians": len(asset.gaussians),
            "pad_names": list(asset.pad_names),
            "frames": "link-local: pose with rigid_transform(means, quats, link_id, "
                      "link_poses[link_names])",
            **asset.meta}
    js.write_text(json.dumps(info, indent=2) + "\n")
    return ply, js


# =========================================================================== CLI
def _parse_guess(text: str):
    if text in ("pca", "identity"):
        return text
    p = Path(text)
    if not p.is_file():
        raise ConfigError(f"--scan-frame-guess {text!r} is neither 'pca', 'identity' nor a file")
    T = np.load(p) if p.suffix == ".npy" else np.loadtxt(p)
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise AssetError(f"{p.name}: scan frame guess has shape {list(T.shape)}, expected 4x4")
    return T


def main(argv: list[str] | None = None) -> int:
    """``gausstac build-asset``: write ``gaussians.ply`` + ``links.json``."""
    import time

    ap = argparse.ArgumentParser(
        prog="gausstac build-asset",
        description="Hand Gaussians (gaussians.ply + links.json, link-local frames) from a "
                    "URDF's visual meshes, or from a scan aligned to the URDF.")
    ap.add_argument("--urdf", default=None,
                    help="URDF file (default: ManiSkill's allegro_hand_right.urdf)")
    ap.add_argument("--out", default=None, help="output folder (default assets/<urdf stem>/)")
    ap.add_argument("--spacing", type=float, default=DEFAULT_SPACING,
                    help="sample spacing in metres (default %(default)s)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scan", default=None,
                    help="scan to align instead of sampling meshes: Gaussian .ply, point "
                         ".ply, .xyz or .npy")
    ap.add_argument("--scan-frame-guess", default="pca",
                    help="initial scan->hand alignment: 'pca' (default), 'identity', or a "
                         ".npy/.txt file with a 4x4 matrix")
    ap.add_argument("--ref-q", default=None,
                    help="reference joint positions of the scan: comma-separated radians in "
                         "URDF joint order, or a JSON object name->value (default all 0)")
    ap.add_argument("--max-distance", type=float, default=0.01,
                    help="drop scan points farther than this from the aligned hand (metres)")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    urdf = Path(args.urdf) if args.urdf else default_urdf()
    out = Path(args.out) if args.out else Path("assets") / urdf.stem
    t0 = time.perf_counter()
    if args.scan:
        q = None
        if args.ref_q:
            text = args.ref_q.strip()
            try:
                q = json.loads(text) if text.startswith("{") else \
                    [float(v) for v in text.split(",")]
            except ValueError:
                raise ConfigError(f"--ref-q {text!r}: expected comma-separated numbers or a "
                                  "JSON object") from None
        asset, align, _ = build_from_scan(args.scan, urdf, q, init=_parse_guess(
            args.scan_frame_guess), max_distance=args.max_distance, seed=args.seed,
            progress=not args.no_progress)
        print(f"aligned scan: trimmed RMS {align.rms * 1e3:.3f} mm, "
              f"dropped {asset.meta['dropped']} points")
    else:
        asset = build_from_urdf(urdf, args.spacing, seed=args.seed,
                                progress=not args.no_progress)
    ply, js = save_asset(out, asset)
    dt = time.perf_counter() - t0
    print(f"{len(asset.gaussians)} Gaussians on {len(asset.link_names)} links in {dt:.1f} s "
          f"-> {ply} ({ply.stat().st_size / 1e6:.2f} MB), {js}")
    for name, n in asset.counts().items():
        print(f"  {name:16s} {n}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
