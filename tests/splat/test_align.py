"""Scans: file formats, rigid alignment to the URDF hand (PCA starts + trimmed ICP) and
labelling of points with links."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gausstac_maniskill.errors import AssetError, ConfigError
from gausstac_maniskill.splat import GaussianSet, save_ply
from gausstac_maniskill.splat.align import align_point_clouds, assign_links, load_scan
from gausstac_maniskill.splat.build import sample_posed_hand
from gausstac_maniskill.transforms import transform_points


def errors(T_est, T_scan):
    """(degrees, metres) of ``T_est @ T_scan``: zero when ``T_est`` undoes ``T_scan``."""
    E = T_est @ T_scan
    ang = math.degrees(math.acos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
    return ang, float(np.linalg.norm(E[:3, 3]))


@pytest.fixture(scope="module")
def reference(hand_model, hand_meshes):
    """Oriented 1.5 mm samples of the hand at the reference pose and their links."""
    return sample_posed_hand(hand_model, 1.5e-3, seed=1, meshes=hand_meshes)


def test_icp_recovers_the_scan_transform_and_the_links(hand_model, hand_meshes, reference,
                                                        rigid_motion):
    """Noisy (0.3 mm) samples of the hand moved by a known rigid transform (~30°, few cm):
    recovered within 1 mm / 1° from the PCA starts and from a rough guess; >= 95 % of
    the points get their true link."""
    ref_p, ref_n, ref_l = reference
    rng = np.random.default_rng(11)
    pts, _, truth = sample_posed_hand(hand_model, 2.5e-3, seed=7, meshes=hand_meshes)
    T = rigid_motion(rng)
    scan = transform_points(T, pts + rng.normal(scale=3e-4, size=pts.shape))
    align = align_point_clouds(scan, ref_p, ref_n)
    ang, dt = errors(align.transform, T)
    assert ang < 1.0 and dt < 1e-3, (ang, dt)
    assert align.rms < 1e-3
    assert len(align.candidates) == 24  # 6 axis orders x 4 proper sign flips
    guess = T @ rigid_motion(rng, max_deg=5.0, max_t=0.005)  # 5°, 5 mm off
    near = align_point_clouds(scan, ref_p, ref_n, init=np.linalg.inv(guess))
    assert [c[0] for c in near.candidates] == ["guess"]
    assert np.allclose(near.transform, align.transform, atol=1e-4)
    label, dist = assign_links(transform_points(align.transform, scan), ref_p, ref_l,
                               hand_meshes, hand_model.visual_links,
                               hand_model.forward_kinematics())
    assert np.mean(label == truth) >= 0.95
    assert np.median(dist) < 1e-3


def test_bad_guess_is_refused(reference):
    ref_p, ref_n, _ = reference
    with pytest.raises(ConfigError, match="scan frame guess"):
        align_point_clouds(ref_p[:100], ref_p, ref_n, init=np.eye(3))


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
        p, g, rgb = load_scan(tmp_path / name)
        assert g is None and np.allclose(p, pts)
    assert np.allclose(load_scan(tmp_path / "s.npy")[2], 1.0)
    save_ply(tmp_path / "g.ply", GaussianSet.create(pts))
    p, g, _ = load_scan(tmp_path / "g.ply")
    assert isinstance(g, GaussianSet) and np.allclose(p, pts, atol=1e-6)
    with pytest.raises(AssetError, match="gone.xyz"):
        load_scan(tmp_path / "gone.xyz")
    np.save(tmp_path / "few.npy", pts[:5])
    with pytest.raises(AssetError, match="few.npy: only 5 points"):
        load_scan(tmp_path / "few.npy")
