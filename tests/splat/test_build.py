"""Hand Gaussians asset builder: URDF meshes -> link-local Gaussians, scan alignment."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from gausstac_maniskill.errors import AssetError, ConfigError
from gausstac_maniskill.splat import (GaussianSet, intrinsics_from_fov, load_ply, look_at,
                                      quat_to_rotmat, render, rigid_transform)
from gausstac_maniskill.splat import build as B
from gausstac_maniskill.transforms import rotation_about

COARSE = 4e-3  # spacing of the test builds, metres


@pytest.fixture(scope="module")
def model():
    return B.parse_urdf(B.default_urdf())


@pytest.fixture(scope="module")
def meshes(model):
    return B.load_link_meshes(model)


@pytest.fixture(scope="module")
def asset():
    return B.build_from_urdf(spacing=COARSE, progress=False)


def _random_q(model, seed=0):
    """Joint positions within the URDF limits (dict name -> radians)."""
    import xml.etree.ElementTree as ET

    rng = np.random.default_rng(seed)
    root = ET.parse(model.path).getroot()
    q = {}
    for j in root.findall("joint"):
        lim = j.find("limit")
        if j.get("name") in model.joint_names and lim is not None:
            q[j.get("name")] = rng.uniform(float(lim.get("lower")), float(lim.get("upper")))
    return q


def _posed_link_mesh(meshes, name, T):
    import trimesh

    m = trimesh.util.concatenate([c.mesh for c in meshes[name]])
    m.apply_transform(T)
    return m


# --------------------------------------------------------------------------- URDF path
def test_every_visual_link_gets_gaussians(asset, model, meshes):
    assert asset.link_names == model.visual_links
    assert len(asset.link_names) == 21  # base, 4 x (4 links + tip) except thumb: 4 + tip
    counts = asset.counts()
    for name in asset.link_names:
        area = sum(c.mesh.area for c in meshes[name])
        # blue-noise density ≈ 1 / spacing²
        assert 0.7 < counts[name] / (area / COARSE ** 2) < 1.3, (name, counts[name])
    g = asset.gaussians
    assert torch.all(g.group == -1)
    assert g.sh_degree == 0
    assert torch.allclose(g.opacities, torch.full_like(g.opacities, 1 / (1 + math.exp(-4))))
    s = g.scales
    assert torch.allclose(s[:, 0], torch.full_like(s[:, 0], B.IN_PLANE_SCALE * COARSE))
    assert torch.allclose(s[:, 2], torch.full_like(s[:, 2], COARSE / 20))


def test_colours_follow_mesh_materials(asset):
    """Allegro .mtl files: links 'black_metal' (Kd 0.004 -> 1/255), tips 'white_head' (0.95)."""
    from gausstac_maniskill.splat import sh_dc_to_rgb

    rgb = sh_dc_to_rgb(asset.gaussians.sh[:, 0, :])
    tip = asset.link_names.index("link_3.0_tip")
    palm = asset.link_names.index("base_link")
    lid = asset.gaussians.link_id
    assert torch.allclose(rgb[lid == tip], torch.tensor(242 / 255), atol=1e-5)
    assert torch.allclose(rgb[lid == palm], torch.tensor(1 / 255), atol=1e-5)


def test_fk_matches_mujoco_and_means_lie_on_posed_meshes(asset, model, meshes):
    """Poses from MuJoCo (independent URDF loader) at random joints: our FK agrees, and
    every link-local Gaussian posed by rigid_transform lies on its link's posed mesh
    surface with its local z along the surface normal."""
    pytest.importorskip("mujoco")
    from gausstac_maniskill.pose.mujoco_source import MujocoPoseSource

    q = _random_q(model, seed=3)
    src = MujocoPoseSource()
    src.set_joint_positions(q)
    mj = src.link_poses(asset.link_names)[0].to(torch.float64)
    ours = model.link_poses(asset.link_names, q)
    assert torch.allclose(ours, mj, atol=1e-6), (ours - mj).abs().max()

    g = asset.gaussians
    means, quats = rigid_transform(g.means.double(), g.quats.double(), g.link_id, mj)
    normals = quat_to_rotmat(quats)[:, :, 2].numpy()
    means = means.numpy()
    for i, name in enumerate(asset.link_names):
        sel = (g.link_id == i).numpy()
        m = _posed_link_mesh(meshes, name, mj[i].numpy())
        _, dist, tri = m.nearest.on_surface(means[sel])
        assert dist.max() < 1e-3, (name, dist.max())
        dots = np.abs(np.einsum("ij,ij->i", normals[sel], m.face_normals[tri]))
        assert np.mean(dots > 0.99) > 0.95, name


def test_ply_round_trip_and_links_json(asset, tmp_path):
    ply, js = B.save_asset(tmp_path / "hand", asset)
    g = load_ply(ply)
    assert torch.equal(g.link_id, asset.gaussians.link_id)
    assert torch.equal(g.group, asset.gaussians.group)
    assert torch.equal(g.means, asset.gaussians.means)
    info = json.loads(js.read_text())
    assert info["link_names"] == asset.link_names
    assert info["urdf"] == "allegro_hand_right.urdf"
    assert info["spacing"] == COARSE
    assert info["counts"] == asset.counts()
    assert sum(info["counts"].values()) == len(g) == info["num_gaussians"]


def test_pad_regions_set_groups(model):
    tips = ["link_3.0_tip", "link_15.0_tip"]
    pads = {t: (lambda p: p[:, 2] > 0.0) for t in tips}
    a = B.build_from_urdf(spacing=COARSE, links=["base_link", *tips], pad_regions=pads,
                          progress=False)
    g = a.gaussians
    assert a.pad_names == tips
    for k, t in enumerate(tips):
        on_link = g.link_id == a.link_names.index(t)
        upper = on_link & (g.means[:, 2] > 0)
        assert upper.sum() > 20
        assert torch.all(g.group[upper] == k)
        assert torch.all(g.group[on_link & ~upper] == -1)
    assert torch.all(g.group[g.link_id == 0] == -1)
    with pytest.raises(ConfigError, match="link_99"):
        B.build_from_urdf(spacing=COARSE, links=["base_link"], pad_regions={"link_99": pads[
            tips[0]]}, progress=False)


# --------------------------------------------------------------------------- small URDFs
PLATE = """<?xml version="1.0"?>
<robot name="plate">
  <material name="blue"><color rgba="0.2 0.6 0.9 1"/></material>
  <link name="plate">
    <visual>
      <origin xyz="0 0 0.01" rpy="0 0 0"/>
      <geometry><box size="0.04 0.04 0.004"/></geometry>
      <material name="blue"/>
    </visual>
  </link>
  {extra}
</robot>
"""


def _write(tmp_path, text, name="robot.urdf"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_flat_surface_is_covered_without_holes(tmp_path):
    """Top face of a box seen head-on at 0.5 mm pixels (spacing 2 mm): every pixel is
    opaque and has the URDF colour. With in-plane σ = spacing/2 this fails (holes)."""
    urdf = _write(tmp_path, PLATE.format(extra=""))
    a = B.build_from_urdf(urdf, spacing=2e-3, progress=False)
    g = a.gaussians
    top = g[g.means[:, 2] > 0.0119]  # top face only (z = 0.012), nothing behind it
    assert len(top) > 0.7 * 0.04 ** 2 / 2e-3 ** 2
    view = look_at((0, 0, 0.012 + 0.06), (0, 0, 0.012), up=(0, 1, 0))[None]
    K = intrinsics_from_fov(64, 64, math.radians(30))[None]
    out = render(top, view, K, 64, 64)
    assert out.alpha.min() > 0.9, out.alpha.min()
    assert torch.allclose(out.rgb[0].mean((0, 1)), torch.tensor([0.2, 0.6, 0.9]), atol=0.05)


def test_cli_writes_asset(tmp_path):
    urdf = _write(tmp_path, PLATE.format(extra=""))
    rc = B.main(["--urdf", str(urdf), "--out", str(tmp_path / "out"), "--spacing", "0.004",
                 "--no-progress"])
    assert rc == 0
    info = json.loads((tmp_path / "out" / "links.json").read_text())
    assert info["link_names"] == ["plate"] and info["robot"] == "plate"
    g = load_ply(tmp_path / "out" / "gaussians.ply")
    assert len(g) == info["counts"]["plate"] > 0


def test_missing_files_raise_asset_error_naming_them(tmp_path):
    with pytest.raises(AssetError, match="nowhere.urdf"):
        B.build_from_urdf(tmp_path / "nowhere.urdf", progress=False)
    missing = PLATE.format(extra='<link name="finger"><visual><geometry>'
                                 '<mesh filename="meshes/missing_finger.obj"/></geometry>'
                                 '</visual></link>')
    with pytest.raises(AssetError, match="missing_finger.obj"):
        B.build_from_urdf(_write(tmp_path, missing), progress=False)


@pytest.mark.parametrize("extra, match", [
    ('<link name="b"/><joint name="j1" type="revolute"><child link="b"/></joint>',
     r"joint name='j1'.*<parent"),
    ('<link name="b"/><joint name="j2" type="fixed"><parent link="plate"/><child link="b"/>'
     '<origin xyz="0 zero 0"/></joint>', r"joint name='j2'.*<origin>.*xyz"),
    ('<link name="b"><visual><geometry><mesh/></geometry></visual></link>',
     r"link name='b'.*<mesh>.*filename"),
    ('<link name="b"', "malformed URDF XML"),
])
def test_malformed_urdf_names_the_element(tmp_path, extra, match):
    with pytest.raises(AssetError, match=match):
        B.parse_urdf(_write(tmp_path, PLATE.format(extra=extra)))


def test_bad_spacing_is_config_error():
    with pytest.raises(ConfigError, match="spacing"):
        B.build_from_urdf(spacing=-1.0, progress=False)


# --------------------------------------------------------------------------- render
def test_render_built_hand_covers_its_silhouette(asset, model, meshes):
    """64x64 render of the posed hand: coverage is sensible and matches the silhouette of
    the posed meshes (dense surface samples projected into the same camera)."""
    q = _random_q(model, seed=5)
    poses = model.link_poses(asset.link_names, q)
    g = asset.gaussians
    means, quats = rigid_transform(g.means, g.quats, g.link_id, poses)
    world = g.replace(means=means.float(), quats=quats.float())
    centre = tuple(means.mean(0).tolist())
    eye = (centre[0] + 0.45, centre[1] + 0.1, centre[2] + 0.1)
    view = look_at(eye, centre)[None]
    K = intrinsics_from_fov(64, 64, math.radians(45))[None]
    out = render(world, view, K, 64, 64)
    mask = out.alpha[0] > 0.5
    frac = mask.float().mean().item()
    assert 0.05 < frac < 0.7, frac

    pts, _, _ = B.sample_posed_hand(model, 1e-3, q, asset.link_names, meshes=meshes)
    cam = pts @ view[0, :3, :3].double().numpy().T + view[0, :3, 3].double().numpy()
    uv = cam[:, :2] / cam[:, 2:] * K[0, 0, 0].item() + 32.0
    px = np.floor(uv).astype(int)
    ok = np.all((px >= 0) & (px < 64), axis=1)
    sil = np.zeros((64, 64), dtype=bool)
    sil[px[ok, 1], px[ok, 0]] = True
    iou = (sil & mask.numpy()).sum() / (sil | mask.numpy()).sum()
    assert iou > 0.8, iou


# --------------------------------------------------------------------------- scans
def _rigid(rng, max_deg=30.0, max_t=0.05):
    T = np.eye(4)
    T[:3, :3] = rotation_about(rng.normal(size=3), math.radians(max_deg))
    T[:3, 3] = rng.uniform(-max_t, max_t, 3)
    return T


def _errors(T_est, T_true_inv):
    E = T_est @ T_true_inv
    ang = math.degrees(math.acos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
    return ang, float(np.linalg.norm(E[:3, 3]))


def test_icp_recovers_scan_transform_and_links(model, meshes):
    """Noisy (0.3 mm) samples of the hand at the reference pose, moved by a known rigid
    transform (~30°, few cm): recovered within 1 mm / 1°, >= 95 % correct link labels."""
    rng = np.random.default_rng(11)
    pts, _, truth = B.sample_posed_hand(model, 2.5e-3, seed=7, meshes=meshes)
    T = _rigid(rng)
    scan = (pts + rng.normal(scale=3e-4, size=pts.shape)) @ T[:3, :3].T + T[:3, 3]
    a, align, label = B.build_from_scan(scan, progress=False)
    ang, dt = _errors(align.transform, T)
    assert ang < 1.0 and dt < 1e-3, (ang, dt)
    acc = float(np.mean(label == truth))
    assert acc >= 0.95, acc
    assert align.rms < 1e-3
    # the link-local means, posed again at the reference pose, are the aligned scan
    order = np.concatenate([np.nonzero(label == i)[0] for i in range(len(a.link_names))])
    poses = model.link_poses(a.link_names)
    back, _ = rigid_transform(a.gaussians.means.double(), a.gaussians.quats.double(),
                              a.gaussians.link_id, poses)
    expect = scan[order] @ align.transform[:3, :3].T + align.transform[:3, 3]
    assert np.abs(back.numpy() - expect).max() < 1e-5


def test_scan_of_gaussians_round_trips_to_link_frames(asset, model):
    """Posed, moved INRIA-style Gaussians (with degree-1 SH) come back in their link frames:
    same means, rotations and (rotated) SH coefficients."""
    rng = np.random.default_rng(2)
    g = asset.gaussians
    sh = torch.cat([g.sh, torch.randn(len(g), 3, 3, generator=torch.Generator().manual_seed(0))
                    * 0.3], dim=1)
    poses = model.link_poses(asset.link_names)
    T = _rigid(rng)
    scan_poses = torch.as_tensor(T) @ poses  # link -> scan frame
    m, q = rigid_transform(g.means.double(), g.quats.double(), g.link_id, scan_poses)
    sh_scan = torch.empty_like(sh)
    for i in range(len(asset.link_names)):
        sel = g.link_id == i
        sh_scan[sel] = B.rotate_sh(sh[sel], scan_poses[i, :3, :3].numpy().T)
    scan = g.replace(means=m.float(), quats=q.float(), sh=sh_scan)
    out, align, label = B.build_from_scan(scan, progress=False)
    truth = g.link_id.numpy()
    assert np.mean(label == truth) > 0.95
    order = np.concatenate([np.nonzero(label == i)[0] for i in range(len(out.link_names))])
    good = label[order] == truth[order]
    src = g[torch.as_tensor(order[good])]
    res = out.gaussians[torch.as_tensor(np.nonzero(good)[0])]
    assert (res.means - src.means).abs().max() < 1e-4
    assert (quat_to_rotmat(res.quats) - quat_to_rotmat(src.quats)).abs().max() < 1e-2
    assert (res.sh - sh[torch.as_tensor(order[good])]).abs().max() < 1e-2


def test_rotate_sh_matches_rotated_evaluation():
    rng = np.random.default_rng(0)
    R = rotation_about(rng.normal(size=3), 1.1)
    sh = torch.as_tensor(rng.normal(size=(5, 16, 3)))
    out = B.rotate_sh(sh, R)
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    new = np.einsum("mk,nkc->nmc", B._sh_basis(d, 3), out.numpy())
    old = np.einsum("mk,nkc->nmc", B._sh_basis(d @ R.T, 3), sh.numpy())
    assert np.abs(new - old).max() < 1e-8
    assert not np.allclose(out.numpy(), sh.numpy())


def test_load_scan_formats(tmp_path):
    from plyfile import PlyData, PlyElement

    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 3))
    np.savetxt(tmp_path / "s.xyz", pts)
    np.save(tmp_path / "s.npy", np.concatenate([pts, np.full((50, 3), 255.0)], 1))
    rec = np.empty(50, dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    rec["x"], rec["y"], rec["z"] = pts.T
    PlyData([PlyElement.describe(rec, "vertex")]).write(str(tmp_path / "s.ply"))
    for name in ("s.xyz", "s.npy", "s.ply"):
        p, g, rgb = B.load_scan(tmp_path / name)
        assert g is None and np.allclose(p, pts)
    assert np.allclose(B.load_scan(tmp_path / "s.npy")[2], 1.0)
    from gausstac_maniskill.splat import save_ply

    save_ply(tmp_path / "g.ply", GaussianSet.create(pts))
    p, g, _ = B.load_scan(tmp_path / "g.ply")
    assert isinstance(g, GaussianSet) and np.allclose(p, pts, atol=1e-6)
    with pytest.raises(AssetError, match="gone.xyz"):
        B.load_scan(tmp_path / "gone.xyz")
