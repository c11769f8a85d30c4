"""Minimal URDF reading: link names and the geometry of a link's collision/visual elements."""
from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import numpy as np

from .errors import AssetError, ConfigError


def default_hand_urdf() -> str:
    """Path of ManiSkill's ``allegro_hand_right.urdf`` (the .obj-mesh variant)."""
    import mani_skill

    return os.path.join(mani_skill.PACKAGE_ASSET_DIR, "robots", "allegro", "allegro_hand_right.urdf")


def _parse(urdf_path: str) -> ET.Element:
    if not os.path.isfile(urdf_path):
        raise AssetError(f"{urdf_path}: URDF file not found")
    try:
        return ET.parse(urdf_path).getroot()
    except ET.ParseError as exc:
        raise AssetError(f"{urdf_path}: malformed URDF XML ({exc})") from None


def link_names(urdf_path: str) -> list[str]:
    """Names of all ``<link>`` elements, in file order."""
    return [l.get("name") for l in _parse(urdf_path).findall("link")]


def rpy_matrix(rpy) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw [rad] -> 3x3 rotation, R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _origin(elem) -> np.ndarray:
    from .transforms import make_pose

    o = elem.find("origin") if elem is not None else None
    if o is None:
        return np.eye(4)
    xyz = [float(v) for v in o.get("xyz", "0 0 0").split()]
    return make_pose(xyz, rpy_matrix(o.get("rpy", "0 0 0").split()))


def link_mesh(urdf_path: str, link: str, kind: str = "collision"):
    """The link's ``kind`` (collision|visual) geometry as one trimesh mesh in the link frame.

    Raises:
        ConfigError: the link does not exist (the message lists close names).
        AssetError: the link has no such geometry, or a mesh file is missing.
    """
    import difflib

    import trimesh

    root = _parse(urdf_path)
    node = next((l for l in root.findall("link") if l.get("name") == link), None)
    if node is None:
        names = [l.get("name") for l in root.findall("link")]
        close = difflib.get_close_matches(link, names, n=3)
        raise ConfigError(f"link {link!r} is not in {os.path.basename(urdf_path)}"
                          + (f"; did you mean {close}?" if close else f"; links: {names}"))
    meshes = []
    for el in node.findall(kind):
        geo = el.find("geometry")
        T = _origin(el)
        m = None
        if geo is None:
            raise AssetError(f"{urdf_path}: link {link!r} <{kind}> has no <geometry>")
        if geo.find("mesh") is not None:
            g = geo.find("mesh")
            path = os.path.join(os.path.dirname(urdf_path), g.get("filename", "").replace("package://", ""))
            if not os.path.isfile(path):
                raise AssetError(f"{path}: mesh file of link {link!r} ({kind}) not found")
            m = trimesh.load(path, force="mesh")
            if g.get("scale"):
                m.apply_scale(np.array([float(v) for v in g.get("scale").split()]))
        elif geo.find("box") is not None:
            m = trimesh.creation.box(extents=[float(v) for v in geo.find("box").get("size").split()])
        elif geo.find("sphere") is not None:
            m = trimesh.creation.icosphere(3, radius=float(geo.find("sphere").get("radius")))
        elif geo.find("cylinder") is not None:
            c = geo.find("cylinder")
            m = trimesh.creation.cylinder(radius=float(c.get("radius")), height=float(c.get("length")))
        if m is not None:
            m.apply_transform(T)
            meshes.append(m)
    if not meshes:
        raise AssetError(f"{urdf_path}: link {link!r} has no <{kind}> geometry")
    return meshes[0] if len(meshes) == 1 else trimesh.util.concatenate(meshes)
