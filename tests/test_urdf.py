"""The URDF reader: parsing, forward kinematics, mesh path resolution, link meshes."""
from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from gausstac_maniskill.errors import AssetError, ConfigError
from gausstac_maniskill.urdf import (default_hand_urdf, link_mesh, link_names, parse_urdf,
                                     resolve_mesh_path)


@pytest.fixture(scope="module")
def allegro():
    return parse_urdf(default_hand_urdf())


def test_allegro_links_joints_and_geometry(allegro):
    assert allegro.name == "allegro_right" and len(allegro.links) == 23
    assert allegro.links[:3] == ["base_link", "palm", "wrist"]
    assert len(allegro.visual_links) == 21  # palm and wrist have no visual
    assert [g.kind for g in allegro.collisions["base_link"]] == ["box"] * 3
    assert len(allegro.joint_names) == 16
    assert link_names(default_hand_urdf()) == allegro.links
    tip = allegro.geometry("link_3.0_tip", "collision")
    assert [g.kind for g in tip] == ["mesh"] and tip[0].filename.endswith("link_tip.obj")
    assert allegro.mesh_path(tip[0]).is_file()
    j = next(j for j in allegro.joints if j.name == "joint_0.0")
    assert j.limits == (-0.47, 0.47)
    with pytest.raises(ConfigError, match=r"'link_3.0_tipp' is not in .*link_3.0_tip"):
        allegro.geometry("link_3.0_tipp")


def test_fk_matches_mujoco(allegro):
    """Link poses at random joints within the limits agree with MuJoCo's independent
    URDF loader."""
    pytest.importorskip("mujoco")
    from gausstac_maniskill.pose.mujoco_source import MujocoPoseSource

    rng = np.random.default_rng(3)
    q = {j.name: rng.uniform(*j.limits) for j in allegro.joints if j.limits}
    assert len(q) == 16
    names = allegro.visual_links
    src = MujocoPoseSource()
    src.set_joint_positions(q)
    mj = src.link_poses(names)[0].to(torch.float64)
    ours = allegro.link_poses(names, q)
    assert torch.allclose(ours, mj, atol=1e-6), (ours - mj).abs().max()
    assert not torch.allclose(ours, allegro.link_poses(names))  # q moved the links


def test_joint_positions_as_mapping_or_sequence(allegro):
    names = allegro.joint_names
    seq = np.linspace(-0.2, 0.3, len(names))
    assert allegro.joint_map(seq) == dict(zip(names, seq.tolist()))
    assert allegro.joint_map({names[2]: 0.1}) == {n: (0.1 if n == names[2] else 0.0) for n in names}
    with pytest.raises(ConfigError, match="unknown joint 'joint_99'"):
        allegro.joint_map({"joint_99": 0.0})
    with pytest.raises(ConfigError, match="3 values.*16 movable joints"):
        allegro.forward_kinematics([0.0, 0.0, 0.0])


# --------------------------------------------------------------------------- small URDFs
ROBOT = """<?xml version="1.0"?>
<robot name="r">
  <link name="a">
    <visual><geometry><mesh filename="{a}"/></geometry></visual>
    <collision><origin xyz="0 0 0.5"/><geometry><box size="1 2 3"/></geometry></collision>
  </link>
  <link name="b">
    <visual><origin xyz="1 0 0"/><geometry><mesh filename="{b}" scale="2"/></geometry></visual>
  </link>
  <joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1"/></joint>
</robot>
"""


def _mesh_file(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=(0.01, 0.02, 0.03)).export(path)
    return path


def test_package_and_relative_mesh_paths(tmp_path):
    """``package://NAME/REST`` is found as D/REST (D = the package root above the URDF)
    and as D/NAME/REST (a package folder beside the URDF); a plain relative path is
    relative to the URDF's folder. Both loaders of the package use the rule."""
    x = _mesh_file(tmp_path / "pkgname" / "meshes" / "x.obj")
    y = _mesh_file(tmp_path / "pkgname" / "meshes" / "y.obj")
    inside = tmp_path / "pkgname" / "urdf" / "robot.urdf"  # ROS layout: <pkg>/urdf/*.urdf
    inside.parent.mkdir()
    inside.write_text(ROBOT.format(a="package://pkgname/meshes/x.obj", b="../meshes/y.obj"))
    beside = tmp_path / "robot.urdf"  # the package folder next to the URDF
    beside.write_text(ROBOT.format(a="package://pkgname/meshes/x.obj",
                                   b="pkgname/meshes/y.obj"))
    for urdf in (inside, beside):
        model = parse_urdf(urdf)
        a, b = model.visuals["a"][0], model.visuals["b"][0]
        assert model.mesh_path(a).resolve() == x.resolve()
        assert model.mesh_path(b).resolve() == y.resolve()
        mb = link_mesh(urdf, "b", "visual")  # scaled by 2, then moved by the origin
        assert np.allclose(mb.extents, [0.02, 0.04, 0.06])
        assert np.allclose(mb.centroid, [1, 0, 0])
    assert resolve_mesh_path(beside, f"file://{x}") == x


def test_missing_mesh_names_the_urdf_and_the_field(tmp_path):
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(ROBOT.format(a="package://pkgname/meshes/gone.obj", b="meshes/none.obj"))
    model = parse_urdf(urdf)  # parsing does not need the meshes
    assert link_names(urdf) == ["a", "b"]
    with pytest.raises(AssetError, match=r"robot\.urdf: <link name='a'> <visual> 0 <mesh> "
                                         r"filename='package://pkgname/meshes/gone\.obj'"):
        model.mesh_path(model.visuals["a"][0])
    with pytest.raises(AssetError, match=r"robot\.urdf.*<link name='b'>.*meshes/none\.obj"):
        link_mesh(urdf, "b", "visual")


def test_link_mesh_primitives_and_missing_geometry(tmp_path):
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(ROBOT.format(a="a.obj", b="b.obj"))
    box = link_mesh(urdf, "a")  # collision: the box moved up by its origin
    assert np.allclose(box.bounds, [[-0.5, -1, -1], [0.5, 1, 2]])
    with pytest.raises(AssetError, match="link 'b' has no <collision> geometry"):
        link_mesh(urdf, "b")
    urdf.write_text(ROBOT.format(a="a.obj", b="b.obj").replace(
        '<box size="1 2 3"/>', '<capsule radius="1" length="2"/>'))
    with pytest.raises(AssetError, match=r"robot\.urdf: <link name='a'> <collision> 0 "
                                         r"<capsule>: unsupported geometry"):
        link_mesh(urdf, "a")


PLATE = """<?xml version="1.0"?>
<robot name="plate">
  <link name="plate">
    <visual><geometry><box size="0.04 0.04 0.004"/></geometry></visual>
  </link>
  {extra}
</robot>
"""


@pytest.mark.parametrize("extra, match", [
    ('<link name="b"/><joint name="j1" type="revolute"><child link="b"/></joint>',
     r"joint name='j1'.*<parent"),
    ('<link name="b"/><joint name="j2" type="fixed"><parent link="plate"/><child link="b"/>'
     '<origin xyz="0 zero 0"/></joint>', r"joint name='j2'.*<origin>.*xyz"),
    ('<link name="b"/><joint name="j3" type="revolute"><parent link="plate"/><child link="b"/>'
     '<axis xyz="0 0 0"/></joint>', r"joint name='j3'.*<axis> is zero"),
    ('<link name="b"><visual><geometry><mesh/></geometry></visual></link>',
     r"link name='b'.*<mesh>.*filename"),
    ('<link name="plate"/>', r"link name='plate'.*defined twice"),
    ('<link name="b"', "malformed URDF XML"),
])
def test_malformed_urdf_names_the_element(tmp_path, extra, match):
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(PLATE.format(extra=extra))
    with pytest.raises(AssetError, match=match):
        parse_urdf(urdf)


def test_fixed_joint_may_have_a_zero_axis_and_missing_file_is_named(tmp_path):
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(PLATE.format(extra='<link name="b"/><joint name="f" type="fixed">'
                                       '<parent link="plate"/><child link="b"/>'
                                       '<origin xyz="0 0 0.1"/><axis xyz="0 0 0"/></joint>'))
    fk = parse_urdf(urdf).forward_kinematics()
    assert np.allclose(fk["b"][:3, 3], [0, 0, 0.1])
    with pytest.raises(AssetError, match="nowhere.urdf"):
        parse_urdf(tmp_path / "nowhere.urdf")


def test_urdf_with_new_collisions_loads_from_anywhere(tmp_path):
    """write_urdf_with_collisions swaps one link's collision geometry and makes every mesh
    path absolute, so the copy in another folder reads like the original."""
    from gausstac_maniskill.urdf import write_urdf_with_collisions

    src = default_hand_urdf()
    box = trimesh.creation.box(extents=(0.01, 0.02, 0.03))
    box.export(tmp_path / "core.obj")
    out = write_urdf_with_collisions(src, tmp_path / "sub" / "hand.urdf", {"link_3.0_tip": tmp_path / "core.obj"})
    np.testing.assert_allclose(link_mesh(out, "link_3.0_tip").extents, (0.01, 0.02, 0.03), atol=1e-9)
    np.testing.assert_allclose(link_mesh(out, "link_7.0_tip").vertices, link_mesh(src, "link_7.0_tip").vertices)
    np.testing.assert_allclose(link_mesh(out, "link_2.0", "visual").vertices, link_mesh(src, "link_2.0", "visual").vertices)
    assert parse_urdf(out).links == parse_urdf(src).links
    two = write_urdf_with_collisions(src, tmp_path / "two.urdf", {"link_3.0_tip": [tmp_path / "core.obj"] * 2})
    assert len(parse_urdf(two).geometry("link_3.0_tip", "collision")) == 2
    with pytest.raises(ConfigError, match="link_99"):
        write_urdf_with_collisions(src, tmp_path / "x.urdf", {"link_99": tmp_path / "core.obj"})
