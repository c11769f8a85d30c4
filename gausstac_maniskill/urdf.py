"""URDF reading: links, joints, visual and collision geometry, materials, forward kinematics.

The one URDF reader of the package (hand Gaussians, pad meshes, agents).
:func:`parse_urdf` gives a :class:`URDFModel`; :func:`link_mesh` gives a link's
geometry as one trimesh mesh.

Mesh paths
----------
``<mesh filename=...>`` is resolved by :func:`resolve_mesh_path`, the same way for
every caller:

* ``file:///abs/path`` or an absolute path: used as written;
* a relative path: relative to the folder of the URDF file;
* ``package://NAME/REST``: the first existing file among ``D/NAME/REST`` (a
  package folder NAME beside or above the URDF) and ``D/REST`` (D is the package
  root itself, whatever its name on disk), for D = the URDF's folder, then each
  of its parents, nearest first.

A mesh that is not found raises :class:`~gausstac_maniskill.errors.AssetError`
naming the URDF file, the element and the ``filename`` as written. Paths are
resolved when a mesh is needed, not while parsing, so link names and joints can
be read from a URDF whose meshes are absent.

Units: metres, radians.
"""
from __future__ import annotations

import difflib
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from .errors import AssetError, ConfigError
from .transforms import make_pose, rotation_about

__all__ = [
    "MOVABLE_JOINTS",
    "URDFGeometry",
    "URDFJoint",
    "URDFModel",
    "default_hand_urdf",
    "link_mesh",
    "link_names",
    "parse_urdf",
    "primitive_mesh",
    "resolve_mesh_path",
    "rpy_matrix",
    "write_urdf_with_collisions", "write_urdf_with_meshes",
    "write_floating_urdf",
    "FLOATING_JOINTS",
]

MOVABLE_JOINTS = ("revolute", "continuous", "prismatic")
JOINT_TYPES = MOVABLE_JOINTS + ("fixed", "floating", "planar")


def default_hand_urdf() -> str:
    """Path of ManiSkill's ``allegro_hand_right.urdf`` (the .obj-mesh variant)."""
    import mani_skill

    return os.path.join(mani_skill.PACKAGE_ASSET_DIR, "robots", "allegro", "allegro_hand_right.urdf")


def rpy_matrix(rpy) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw [rad] -> 3x3 rotation, R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


@dataclass
class URDFGeometry:
    """One ``<visual>`` or ``<collision>`` element of a link.

    Attributes:
        origin: [4, 4] geometry -> link transform (metres).
        kind: the geometry tag: ``"mesh" | "box" | "cylinder" | "sphere"`` (others,
            e.g. ``"capsule"``, are kept and refused when meshed).
        filename: ``<mesh filename>`` as written in the URDF (``kind == "mesh"``),
            else None; see :meth:`URDFModel.mesh_path`.
        scale: [3] mesh scale.
        size: box size [3] (metres), (radius, length) for a cylinder, (radius,) for
            a sphere.
        rgba: ``<material><color rgba>`` in [0, 1] (visuals), or None.
        where: the element, for messages (``"<link name='a'> <visual> 0"``).
    """

    origin: np.ndarray
    kind: str
    filename: str | None = None
    scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    size: tuple = ()
    rgba: tuple | None = None
    where: str = ""


@dataclass
class URDFJoint:
    """A URDF joint: child pose = parent pose · origin · motion(q) about/along ``axis``.

    Attributes:
        origin: [4, 4] child -> parent transform at q = 0 (metres).
        axis: [3] joint axis in the child frame (not normalised).
        limits: ``<limit lower upper>`` (radians / metres) of a revolute or
            prismatic joint, else None.
    """

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    limits: tuple[float, float] | None = None


@dataclass
class URDFModel:
    """The kinematic tree and geometry of a URDF.

    Attributes:
        path: the URDF file.
        name: ``<robot name>``.
        links: every link name, in file order.
        visuals: link name -> its ``<visual>`` geometry (links without any are absent).
        collisions: link name -> its ``<collision>`` geometry (likewise).
        joints: every joint, in file order.
    """

    path: Path
    name: str
    links: list[str]
    visuals: dict[str, list[URDFGeometry]]
    collisions: dict[str, list[URDFGeometry]]
    joints: list[URDFJoint]

    @property
    def visual_links(self) -> list[str]:
        """Links with at least one visual, in URDF (file) order: the default link order."""
        return [n for n in self.links if self.visuals.get(n)]

    @property
    def joint_names(self) -> list[str]:
        """Names of the movable (revolute, continuous, prismatic) joints, file order."""
        return [j.name for j in self.joints if j.type in MOVABLE_JOINTS]

    def geometry(self, link: str, kind: str = "visual") -> list[URDFGeometry]:
        """The ``kind`` (``"visual"`` or ``"collision"``) geometry of ``link`` (may be empty).

        Raises:
            ConfigError: ``link`` is not in the URDF (the message lists close names).
        """
        if kind not in ("visual", "collision"):
            raise ConfigError(f"geometry kind {kind!r} must be 'visual' or 'collision'")
        if link not in self.links:
            close = difflib.get_close_matches(link, self.links, n=3)
            raise ConfigError(f"link {link!r} is not in {self.path.name}"
                              + (f"; did you mean {close}?" if close else f"; links: {self.links}"))
        return (self.visuals if kind == "visual" else self.collisions).get(link, [])

    def mesh_path(self, geom: URDFGeometry) -> Path:
        """The existing file of a mesh geometry (rule: :func:`resolve_mesh_path`)."""
        return resolve_mesh_path(self.path, geom.filename, geom.where)

    def joint_map(self, q=None) -> dict[str, float]:
        """Joint positions as name -> value (radians / metres) for every movable joint.

        Args:
            q: ``None`` (all zero), a mapping joint name -> value (missing joints
                are 0), or a sequence in :attr:`joint_names` order.

        Raises:
            ConfigError: an unknown joint name, or a sequence of the wrong length.
        """
        names = self.joint_names
        if q is None:
            return {n: 0.0 for n in names}
        if isinstance(q, Mapping):
            unknown = [k for k in q if k not in names]
            if unknown:
                raise ConfigError(f"unknown joint {unknown[0]!r} in joint positions "
                                  f"(movable joints: {', '.join(names)})")
            return {n: float(q.get(n, 0.0)) for n in names}
        vals = np.asarray(q, dtype=np.float64).reshape(-1)
        if vals.shape[0] != len(names):
            raise ConfigError(f"joint positions have {vals.shape[0]} values, the URDF "
                              f"{self.path.name} has {len(names)} movable joints")
        return dict(zip(names, vals.tolist()))

    def forward_kinematics(self, q=None) -> dict[str, np.ndarray]:
        """World [4, 4] pose of every link, the root link(s) at the identity.

        Args:
            q: joint positions, as :meth:`joint_map` takes them.
        """
        qmap = self.joint_map(q)
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
                    motion[:3, :3] = rotation_about(j.axis, v)
                elif j.type == "prismatic":
                    motion[:3, 3] = j.axis / np.linalg.norm(j.axis) * v
                T = pose_of(j.parent, depth + 1) @ j.origin @ motion
            poses[link] = T
            return T

        for link in self.links:
            pose_of(link)
        return poses

    def link_poses(self, names: Sequence[str], q=None):
        """[L, 4, 4] float64 torch tensor: world poses of links ``names`` at joints ``q``."""
        import torch

        fk = self.forward_kinematics(q)
        missing = [n for n in names if n not in fk]
        if missing:
            raise ConfigError(f"unknown link {missing[0]!r} for URDF {self.path.name}")
        return torch.as_tensor(np.stack([fk[n] for n in names]), dtype=torch.float64)


# --------------------------------------------------------------------------- parsing
def _floats(elem: ET.Element, attr: str, n: int, default, where: str, file: str) -> np.ndarray:
    """``n`` finite numbers of attribute ``attr`` (a single ``scale`` value is repeated)."""
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
    """[4, 4] transform of ``parent``'s ``<origin xyz rpy>`` (identity if absent)."""
    o = parent.find("origin")
    if o is None:
        return np.eye(4)
    return make_pose(_floats(o, "xyz", 3, (0, 0, 0), f"{where} <origin>", file),
                     rpy_matrix(_floats(o, "rpy", 3, (0, 0, 0), f"{where} <origin>", file)))


def _material_rgba(mat: ET.Element | None, named: dict, where: str, file: str):
    if mat is None:
        return None
    color = mat.find("color")
    if color is not None:
        return tuple(_floats(color, "rgba", 4, None, f"{where} <material><color>", file))
    return named.get(mat.get("name"))


def _geometry(el: ET.Element, named: dict, where: str, file: str) -> URDFGeometry:
    """One ``<visual>`` / ``<collision>`` element."""
    geom = el.find("geometry")
    if geom is None or len(geom) == 0:
        raise AssetError(f"{file}: {where} has no <geometry>")
    g = geom[0]
    out = URDFGeometry(_origin(el, where, file), g.tag,
                       rgba=_material_rgba(el.find("material"), named, where, file),
                       where=f"{where} <{g.tag}>")
    if g.tag == "mesh":
        out.filename = g.get("filename")
        if not out.filename:
            raise AssetError(f"{file}: {where} <mesh> has no 'filename' attribute")
        out.scale = _floats(g, "scale", 3, (1, 1, 1), f"{where} <mesh>", file)
    elif g.tag == "box":
        out.size = tuple(_floats(g, "size", 3, None, f"{where} <box>", file))
    elif g.tag == "cylinder":
        out.size = (_floats(g, "radius", 1, None, f"{where} <cylinder>", file)[0],
                    _floats(g, "length", 1, None, f"{where} <cylinder>", file)[0])
    elif g.tag == "sphere":
        out.size = (_floats(g, "radius", 1, None, f"{where} <sphere>", file)[0],)
    return out


def _joint(jt: ET.Element, i: int, link_set: set, file: str) -> URDFJoint:
    name = jt.get("name") or f"#{i}"
    where = f"<joint name={name!r}>"
    jtype = jt.get("type")
    if jtype not in JOINT_TYPES:
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
    if jtype in MOVABLE_JOINTS and np.linalg.norm(axis) < 1e-12:
        raise AssetError(f"{file}: {where} <axis> is zero")
    lim, limits = jt.find("limit"), None
    if lim is not None and jtype in ("revolute", "prismatic"):
        limits = tuple(float(_floats(lim, b, 1, (0.0,), f"{where} <limit>", file)[0])
                       for b in ("lower", "upper"))
    return URDFJoint(name, jtype, ends["parent"], ends["child"], _origin(jt, where, file), axis,
                     limits)


def parse_urdf(path: str | os.PathLike) -> URDFModel:
    """Parse the links, joints, visuals and collisions of a URDF file.

    Mesh files are not opened (nor looked for) here: see :meth:`URDFModel.mesh_path`.

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
    links: list[str] = []
    geometry = {"visual": {}, "collision": {}}
    for i, link in enumerate(root.findall("link")):
        name = link.get("name")
        if not name:
            raise AssetError(f"{file}: <link> number {i} has no 'name' attribute")
        if name in links:
            raise AssetError(f"{file}: <link name={name!r}> is defined twice")
        links.append(name)
        for kind, table in geometry.items():
            items = [_geometry(el, named, f"<link name={name!r}> <{kind}> {k}", file)
                     for k, el in enumerate(link.findall(kind))]
            if items:
                table[name] = items
    link_set = set(links)
    joints = [_joint(jt, i, link_set, file) for i, jt in enumerate(root.findall("joint"))]
    return URDFModel(path, root.get("name", path.stem), links, geometry["visual"],
                     geometry["collision"], joints)


def link_names(urdf_path: str | os.PathLike) -> list[str]:
    """Names of all ``<link>`` elements, in file order."""
    return parse_urdf(urdf_path).links


# --------------------------------------------------------------------------- mesh paths
def resolve_mesh_path(urdf: str | os.PathLike, filename: str, where: str = "<mesh>") -> Path:
    """The existing file a URDF ``<mesh filename>`` names (rule in the module docstring).

    Args:
        urdf: the URDF file the filename was read from.
        filename: the attribute as written (``package://``, ``file://``, relative
            or absolute).
        where: the element, for the error message.

    Raises:
        AssetError: no candidate exists; names the URDF, the element, the
            filename as written and the places tried.
    """
    urdf = Path(urdf)
    if filename.startswith("file://"):
        candidates = [Path(filename[len("file://"):])]
    elif filename.startswith("package://"):
        package, *rest = Path(filename[len("package://"):]).parts or ("",)
        rest = Path(*rest)
        candidates = [c for base in [urdf.parent, *urdf.parent.parents]
                      for c in (base / package / rest, base / rest)]
    else:
        p = Path(filename)
        candidates = [p if p.is_absolute() else urdf.parent / p]
    for c in candidates:
        if c.is_file():
            return c
    tried = ", ".join(str(c) for c in candidates[:4]) + (" ..." if len(candidates) > 4 else "")
    raise AssetError(f"{urdf}: {where} filename={filename!r}: mesh file not found "
                     f"(tried {tried})")


def write_urdf_with_meshes(urdf: str | os.PathLike, folder: str | os.PathLike, meshes: Mapping[str, Sequence],
                           stem: str = "collision") -> Path:
    """``folder/<urdf's name>``: :func:`write_urdf_with_collisions` of ``urdf`` with each link of
    ``meshes`` colliding with its trimesh meshes (link frame), exported once to
    ``folder/<link>_<stem><i>.obj`` (atomically: several processes may write the same files);
    nothing is written when that URDF exists (a folder named by a digest of the content)."""
    folder = Path(folder)
    out = folder / os.path.basename(urdf)
    if not out.is_file():
        files = {}
        for link, pieces in meshes.items():
            files[link] = [folder / f"{link}_{stem}{i}.obj" for i in range(len(pieces))]
            for piece, path in zip(pieces, files[link]):
                tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.obj")
                piece.export(tmp)
                os.replace(tmp, path)
        write_urdf_with_collisions(urdf, out, files)
    return out


def write_urdf_with_collisions(urdf: str | os.PathLike, out: str | os.PathLike,
                               collisions: Mapping[str, str | os.PathLike | Sequence]) -> Path:
    """Write a copy of ``urdf`` to ``out`` whose links in ``collisions`` collide with the
    given meshes instead of their own ``<collision>`` elements.

    Every ``<mesh filename>`` of the copy is made absolute (resolved with
    :func:`resolve_mesh_path`; one that cannot be resolved is kept as written), so the copy
    loads from any folder. The new meshes are in their link's frame (identity ``<origin>``).
    The file is written atomically (several processes may write the same one).

    Args:
        urdf: the source URDF file.
        out: the file to write.
        collisions: link name -> mesh file [m, link frame], or a list of them (one
            ``<collision>`` each: convex pieces, which SAPIEN keeps apart).

    Raises:
        AssetError: ``urdf`` is missing or malformed.
        ConfigError: a link in ``collisions`` is not in the URDF.
    """
    model = parse_urdf(urdf)  # checks the file and gives the error messages
    missing = sorted(set(collisions) - set(model.links))
    if missing:
        raise ConfigError(f"{urdf}: write_urdf_with_collisions: no links {missing} (links: {model.links})")
    tree = ET.parse(urdf)
    _absolute_meshes(tree, urdf)
    for link in tree.getroot().findall("link"):
        name = link.get("name")
        if name not in collisions:
            continue
        for el in link.findall("collision"):
            link.remove(el)
        files = collisions[name]
        for file in [files] if isinstance(files, (str, os.PathLike)) else files:
            col = ET.SubElement(link, "collision")
            ET.SubElement(ET.SubElement(col, "geometry"), "mesh", filename=str(Path(file).resolve()))
    return _write_atomic(tree, out)


#: Root joints of :func:`write_floating_urdf`, parent to child: x, y, z translation [m] of the
#: root, then rotations [rad] about the x, y and z axes of the frame they move
#: (hand orientation R = Rx(a) Ry(b) Rz(c)).
FLOATING_JOINTS = ("root_x_axis_joint", "root_y_axis_joint", "root_z_axis_joint",
                   "root_x_rot_joint", "root_y_rot_joint", "root_z_rot_joint")


def write_floating_urdf(urdf: str | os.PathLike, out: str | os.PathLike, travel: float = 2.0) -> Path:
    """Write a copy of the fixed-base ``urdf`` whose root link hangs from a 6-DoF chain of
    massless links: prismatic x, y, z and revolute x, y, z (:data:`FLOATING_JOINTS`), as
    ManiSkill's floating hands are built, so that PD drives on those joints move the hand.

    Mesh filenames are made absolute (as :func:`write_urdf_with_collisions`). The new
    root link is ``root`` (at the world origin when the agent's pose is the identity).

    Args:
        urdf: a URDF with one root link.
        out: the file to write (atomically).
        travel: the prismatic joints' range is [-travel, travel] m (the revolute joints'
            [-2π, 2π] rad).

    Raises:
        AssetError: ``urdf`` is missing or malformed, or has not exactly one root link.
        ConfigError: ``urdf`` already has a link named ``root`` or ``root_arm_*``.
    """
    model = parse_urdf(urdf)
    roots = [n for n in model.links if n not in {j.child for j in model.joints}]
    if len(roots) != 1:
        raise AssetError(f"{urdf}: write_floating_urdf needs exactly one root link, found {roots}")
    chain = ["root"] + [f"root_arm_{i}" for i in range(1, len(FLOATING_JOINTS))] + roots[:1]
    taken = sorted(set(chain[:-1]) & set(model.links))
    if taken:
        raise ConfigError(f"{urdf}: write_floating_urdf: the URDF already has links {taken}")
    tree = ET.parse(urdf)
    robot = tree.getroot()
    _absolute_meshes(tree, urdf)
    for i, name in enumerate(chain[:-1]):
        link = ET.Element("link", name=name)
        inertial = ET.SubElement(link, "inertial")
        ET.SubElement(inertial, "mass", value="0")
        ET.SubElement(inertial, "inertia", ixx="0", ixy="0", ixz="0", iyy="0", iyz="0", izz="0")
        robot.insert(i, link)
    for i, joint in enumerate(FLOATING_JOINTS):
        prismatic = i < 3
        el = ET.SubElement(robot, "joint", name=joint, type="prismatic" if prismatic else "revolute")
        ET.SubElement(el, "parent", link=chain[i])
        ET.SubElement(el, "child", link=chain[i + 1])
        ET.SubElement(el, "axis", xyz=" ".join("1" if k == i % 3 else "0" for k in range(3)))
        span = travel if prismatic else 2 * np.pi
        ET.SubElement(el, "limit", effort="1000", lower=f"{-span:.9g}", upper=f"{span:.9g}", velocity="10")
    return _write_atomic(tree, out)


def _absolute_meshes(tree: ET.ElementTree, urdf) -> None:
    """Make every ``<mesh filename>`` of ``tree`` (read from ``urdf``) absolute, so that a
    copy loads from any folder; one that cannot be resolved is kept as written (SAPIEN
    then reports it)."""
    for mesh in tree.getroot().iter("mesh"):
        filename = mesh.get("filename")
        if filename:
            try:
                mesh.set("filename", str(resolve_mesh_path(urdf, filename).resolve()))
            except AssetError:
                pass


def _write_atomic(tree: ET.ElementTree, out) -> Path:
    """Write ``tree`` to ``out`` atomically (several processes may write the same file)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    tree.write(tmp, encoding="utf-8", xml_declaration=True)
    os.replace(tmp, out)
    return out


# --------------------------------------------------------------------------- meshes
def primitive_mesh(geom: URDFGeometry, urdf_name: str = "URDF"):
    """A box, cylinder or sphere geometry as a trimesh mesh in the geometry frame (metres).

    Raises:
        AssetError: any other kind, naming ``urdf_name`` and the element (``mesh``
            geometry is loaded from its file instead).
    """
    import trimesh

    if geom.kind == "box":
        return trimesh.creation.box(extents=geom.size)
    if geom.kind == "cylinder":
        return trimesh.creation.cylinder(radius=geom.size[0], height=geom.size[1], sections=48)
    if geom.kind == "sphere":
        return trimesh.creation.icosphere(subdivisions=3, radius=geom.size[0])
    raise AssetError(f"{urdf_name}: {geom.where}: unsupported geometry <{geom.kind}>")


def link_mesh(urdf_path: str | os.PathLike, link: str, kind: str = "collision"):
    """The link's ``kind`` (collision|visual) geometry as one trimesh mesh in the link frame.

    Mesh files are loaded with ``trimesh.load(force="mesh")`` (vertices merged),
    scaled, and moved by their ``<origin>``; several elements are concatenated.

    Raises:
        ConfigError: the link does not exist (the message lists close names).
        AssetError: the link has no such geometry, or a mesh file is missing.
    """
    import trimesh

    model = parse_urdf(urdf_path)
    meshes = []
    for geom in model.geometry(link, kind):
        if geom.kind == "mesh":
            m = trimesh.load(str(model.mesh_path(geom)), force="mesh")
            m.apply_scale(geom.scale)
        else:
            m = primitive_mesh(geom, model.path.name)
        m.apply_transform(geom.origin)
        meshes.append(m)
    if not meshes:
        raise AssetError(f"{urdf_path}: link {link!r} has no <{kind}> geometry")
    return meshes[0] if len(meshes) == 1 else trimesh.util.concatenate(meshes)
