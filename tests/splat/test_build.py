"""Hand Gaussians assets: URDF meshes -> link-local Gaussians, scans -> link-local Gaussians,
the asset files and the ``build-asset`` command."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from gausstac_maniskill.errors import AssetError, ConfigError
from gausstac_maniskill.splat import (intrinsics_from_fov, load_ply, look_at, quat_to_rotmat,
                                      render, rigid_transform)
from gausstac_maniskill.splat import build as B
from gausstac_maniskill.splat.sh import rotate_sh

COARSE = 4e-3  # spacing of the test builds, metres


@pytest.fixture(scope="module")
def asset():
    return B.build_from_urdf(spacing=COARSE, progress=False)


def _random_q(model, seed=0):
    """Joint positions within the URDF limits (dict name -> radians)."""
    rng = np.random.default_rng(seed)
    return {j.name: rng.uniform(*j.limits) for j in model.joints if j.limits}


def _posed_link_mesh(meshes, name, T):
    import trimesh

    m = trimesh.util.concatenate([c.mesh for c in meshes[name]])
    m.apply_transform(T)
    return m


# --------------------------------------------------------------------------- URDF path
def test_every_visual_link_gets_gaussians(asset, hand_model, hand_meshes):
    assert asset.link_names == hand_model.visual_links
    assert len(asset.link_names) == 21  # base, 4 x (4 links + tip) except thumb: 4 + tip
    counts = asset.counts()
    for name in asset.link_names:
        area = sum(c.mesh.area for c in hand_meshes[name])
        # blue-noise density ≈ 1 / spacing²
        assert 0.7 < counts[name] / (area / COARSE ** 2) < 1.3, (name, counts[name])
    g = asset.gaussians
    assert torch.all(g.group == -1)
    assert g.sh_degree == 0
    assert torch.allclose(g.opacities, torch.full_like(g.opacities, 1 / (1 + math.exp(-4))))
    s = g.scales
    assert torch.allclose(s[:, 0], torch.full_like(s[:, 0], B.IN_PLANE_SCALE * COARSE))
    assert torch.allclose(s[:, 2], torch.full_like(s[:, 2], COARSE / 20))


def test_means_lie_on_posed_meshes_along_their_normals(asset, hand_model, hand_meshes):
    """At random joints, every link-local Gaussian posed by rigid_transform lies on its
    link's posed mesh surface with its local z along the surface normal (the FK itself
    is checked against MuJoCo in tests/test_urdf.py)."""
    q = _random_q(hand_model, seed=3)
    poses = hand_model.link_poses(asset.link_names, q)
    g = asset.gaussians
    means, quats = rigid_transform(g.means.double(), g.quats.double(), g.link_id, poses)
    normals = quat_to_rotmat(quats)[:, :, 2].numpy()
    means = means.numpy()
    for i, name in enumerate(asset.link_names):
        sel = (g.link_id == i).numpy()
        m = _posed_link_mesh(hand_meshes, name, poses[i].numpy())
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


def test_pad_regions_set_groups():
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
def test_cli_writes_asset(tmp_path, plate_urdf):
    urdf = plate_urdf()
    rc = B.main(["--urdf", str(urdf), "--out", str(tmp_path / "out"), "--spacing", "0.004",
                 "--no-progress"])
    assert rc == 0
    info = json.loads((tmp_path / "out" / "links.json").read_text())
    assert info["link_names"] == ["plate"] and info["robot"] == "plate"
    g = load_ply(tmp_path / "out" / "gaussians.ply")
    assert len(g) == info["counts"]["plate"] > 0


def test_missing_files_raise_asset_error_naming_them(tmp_path, plate_urdf):
    with pytest.raises(AssetError, match="nowhere.urdf"):
        B.build_from_urdf(tmp_path / "nowhere.urdf", progress=False)
    missing = plate_urdf('<link name="finger"><visual><geometry>'
                         '<mesh filename="meshes/missing_finger.obj"/></geometry></visual></link>')
    with pytest.raises(AssetError, match=r"robot.urdf: <link name='finger'>.*missing_finger.obj"):
        B.build_from_urdf(missing, progress=False)


def test_bad_spacing_is_config_error():
    with pytest.raises(ConfigError, match="spacing"):
        B.build_from_urdf(spacing=-1.0, progress=False)


# --------------------------------------------------------------------------- render
def test_render_built_hand_covers_its_silhouette(asset, hand_model, hand_meshes):
    """64x64 render of the posed hand: coverage is sensible and matches the silhouette of
    the posed meshes (dense surface samples projected into the same camera)."""
    q = _random_q(hand_model, seed=5)
    poses = hand_model.link_poses(asset.link_names, q)
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

    pts, _, _ = B.sample_posed_hand(hand_model, 1e-3, q, asset.link_names,
                                    meshes=hand_meshes)
    cam = pts @ view[0, :3, :3].double().numpy().T + view[0, :3, 3].double().numpy()
    uv = cam[:, :2] / cam[:, 2:] * K[0, 0, 0].item() + 32.0
    px = np.floor(uv).astype(int)
    ok = np.all((px >= 0) & (px < 64), axis=1)
    sil = np.zeros((64, 64), dtype=bool)
    sil[px[ok, 1], px[ok, 0]] = True
    iou = (sil & mask.numpy()).sum() / (sil | mask.numpy()).sum()
    assert iou > 0.8, iou


# --------------------------------------------------------------------------- scans
def test_point_scan_is_split_into_link_frames(hand_model, hand_meshes, rigid_motion):
    """Noisy (0.3 mm) samples of the hand at the reference pose, moved by a known rigid
    transform: >= 95 % correct link labels, and the link-local means, posed again at the
    reference pose, are the aligned scan (alignment accuracy: tests/splat/test_align.py)."""
    rng = np.random.default_rng(11)
    pts, _, truth = B.sample_posed_hand(hand_model, 2.5e-3, seed=7, meshes=hand_meshes)
    T = rigid_motion(rng)
    scan = (pts + rng.normal(scale=3e-4, size=pts.shape)) @ T[:3, :3].T + T[:3, 3]
    a, align, label = B.build_from_scan(scan, progress=False)
    assert np.abs(align.transform @ T - np.eye(4)).max() < 1e-2
    acc = float(np.mean(label == truth))
    assert acc >= 0.95, acc
    assert a.meta["source"] == "scan" and a.meta["dropped"] == int((label < 0).sum())
    assert a.meta["reference_joint_positions"] == {n: 0.0 for n in hand_model.joint_names}
    order = np.concatenate([np.nonzero(label == i)[0] for i in range(len(a.link_names))])
    poses = hand_model.link_poses(a.link_names)
    back, _ = rigid_transform(a.gaussians.means.double(), a.gaussians.quats.double(),
                              a.gaussians.link_id, poses)
    expect = scan[order] @ align.transform[:3, :3].T + align.transform[:3, 3]
    assert np.abs(back.numpy() - expect).max() < 1e-5


def test_scan_of_gaussians_round_trips_to_link_frames(asset, hand_model, rigid_motion):
    """Posed, moved INRIA-style Gaussians (with degree-1 SH) come back in their link frames:
    same means, rotations and (rotated) SH coefficients."""
    rng = np.random.default_rng(2)
    g = asset.gaussians
    sh = torch.cat([g.sh, torch.randn(len(g), 3, 3, generator=torch.Generator().manual_seed(0))
                    * 0.3], dim=1)
    poses = hand_model.link_poses(asset.link_names)
    T = rigid_motion(rng)
    scan_poses = torch.as_tensor(T) @ poses  # link -> scan frame
    m, q = rigid_transform(g.means.double(), g.quats.double(), g.link_id, scan_poses)
    sh_scan = torch.empty_like(sh)
    for i in range(len(asset.link_names)):
        sel = g.link_id == i
        sh_scan[sel] = rotate_sh(sh[sel], scan_poses[i, :3, :3].numpy().T)
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



# --------------------------------------------------------------------------- closed links
def test_closed_links_carry_outward_normals(asset, hand_meshes):
    """Every Allegro link mesh bounds a solid with outward face normals, so the build lists
    every link as closed; a Gaussian's local z is then its face's *outward* normal, sign
    included (what lets the splat camera skip those facing away)."""
    from gausstac_maniskill.splat.surface import closed_outward

    assert asset.meta["closed_links"] == [n for n in asset.link_names if closed_outward(hand_meshes[n])]
    assert asset.meta["closed_links"] == asset.link_names
    g = asset.gaussians
    z = quat_to_rotmat(g.quats.double())[:, :, 2].numpy()
    for i, name in enumerate(asset.link_names):
        sel = (g.link_id == i).numpy()
        m = _posed_link_mesh(hand_meshes, name, np.eye(4))
        _, _, tri = m.nearest.on_surface(g.means.double().numpy()[sel])
        dots = np.einsum("ij,ij->i", z[sel], m.face_normals[tri])
        assert np.mean(dots > 0.99) > 0.95, name


@pytest.mark.parametrize("file", ["gaussians.ply", "gaussians_3mm.ply"])
def test_shipped_hand_lists_only_closed_links_with_outward_normals(file, hand_meshes):
    """The shipped Allegro asset (both levels of detail): ``closed_links`` names links whose
    meshes are closed and outward, and their Gaussians' local z points out of the mesh."""
    from gausstac_maniskill.agents.base import load_hand_closed_links
    from gausstac_maniskill.demo import ASSET_DIR
    from gausstac_maniskill.splat.surface import closed_outward

    closed = load_hand_closed_links(str(ASSET_DIR))
    names = json.loads((ASSET_DIR / "links.json").read_text())["link_names"]
    assert closed and all(closed_outward(hand_meshes[n]) for n in closed)
    g = load_ply(ASSET_DIR / file)
    z = quat_to_rotmat(g.quats.double())[:, :, 2].numpy()
    for name in closed:
        sel = (g.link_id == names.index(name)).numpy()
        m = _posed_link_mesh(hand_meshes, name, np.eye(4))
        _, _, tri = m.nearest.on_surface(g.means.double().numpy()[sel])
        assert np.mean(np.einsum("ij,ij->i", z[sel], m.face_normals[tri]) > 0.99) > 0.95, (file, name)
