"""Coloured link meshes of a URDF, blue-noise surface samples and the disc Gaussians on them."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from gausstac_maniskill.errors import AssetError, ConfigError
from gausstac_maniskill.splat import intrinsics_from_fov, look_at, quat_to_rotmat, render
from gausstac_maniskill.splat.sh import sh_dc_to_rgb
from gausstac_maniskill.splat.surface import (IN_PLANE_SCALE, NORMAL_SCALE, gaussians_from_points,
                                              gaussians_from_surface, load_link_meshes,
                                              sample_surface_blue_noise)
from gausstac_maniskill.urdf import parse_urdf

@pytest.fixture
def plate(plate_urdf):
    return parse_urdf(plate_urdf('<link name="bare"/>'))


def _samples(model, link, spacing, seed=0):
    meshes = load_link_meshes(model, [link])[link]
    return sample_surface_blue_noise(meshes, spacing, np.random.default_rng(seed))


def test_blue_noise_density_and_exclusion_radius(plate):
    """≈ area / spacing² samples; no two on the same side closer than 0.65·spacing."""
    from scipy.spatial import cKDTree

    s = 2e-3
    p, n, rgb = _samples(plate, "plate", s)
    area = 2 * 0.04 ** 2 + 4 * 0.04 * 0.004
    assert 0.7 < len(p) / (area / s ** 2) < 1.3
    assert np.allclose(np.linalg.norm(n, axis=1), 1)
    assert np.allclose(rgb, [0.2, 0.6, 0.9])
    pairs = cKDTree(p).query_pairs(0.65 * s, output_type="ndarray")
    same_side = np.einsum("ij,ij->i", n[pairs[:, 0]], n[pairs[:, 1]]) > 0
    assert not same_side.any()


def test_flat_surface_is_covered_without_holes(plate):
    """Top face of a box seen head-on at 0.5 mm pixels (spacing 2 mm): every pixel is
    opaque and has the URDF colour. With in-plane σ = spacing/2 this fails (holes)."""
    p, n, rgb = _samples(plate, "plate", 2e-3)
    top = p[:, 2] > 0.0119  # top face only (z = 0.012), nothing behind it
    assert top.sum() > 0.7 * 0.04 ** 2 / 2e-3 ** 2
    g = gaussians_from_surface(p[top], n[top], rgb[top], 2e-3)
    view = look_at((0, 0, 0.012 + 0.06), (0, 0, 0.012), up=(0, 1, 0))[None]
    K = intrinsics_from_fov(64, 64, math.radians(30))[None]
    out = render(g, view, K, 64, 64)
    assert out.alpha.min() > 0.9, out.alpha.min()
    assert torch.allclose(out.rgb[0].mean((0, 1)), torch.tensor([0.2, 0.6, 0.9]), atol=0.05)


def test_gaussians_are_discs_along_the_normal():
    rng = np.random.default_rng(0)
    normals = rng.normal(size=(20, 3))
    g = gaussians_from_surface(rng.normal(size=(20, 3)), normals, np.full((20, 3), 0.3), 4e-3,
                               link_id=2)
    z = quat_to_rotmat(g.quats.double())[:, :, 2].numpy()
    unit = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    assert np.allclose(z, unit, atol=1e-6)
    assert torch.allclose(g.scales[:, :2], torch.tensor(IN_PLANE_SCALE * 4e-3))
    assert torch.allclose(g.scales[:, 2], torch.tensor(NORMAL_SCALE * 4e-3))
    assert torch.allclose(sh_dc_to_rgb(g.sh[:, 0]), torch.tensor(0.3))
    assert torch.all(g.link_id == 2) and torch.all(g.group == -1)


def test_gaussians_from_points_face_the_plane():
    rng = np.random.default_rng(1)
    pts = np.concatenate([rng.uniform(-0.02, 0.02, (400, 2)), np.zeros((400, 1))], 1)
    g = gaussians_from_points(pts)
    z = quat_to_rotmat(g.quats.double())[:, :, 2].numpy()
    assert np.all(np.abs(z[:, 2]) > 0.99)
    spacing = g.scales[:, 0].double().mean().item() / IN_PLANE_SCALE
    assert 0.5 < spacing / math.sqrt(0.04 ** 2 / 400) < 2  # ≈ one point per spacing²


def test_colours_follow_mesh_materials(hand_model):
    """Allegro .mtl files: links 'black_metal' (Kd 0.004 -> 1/255), tips 'white_head' (0.95)."""
    meshes = load_link_meshes(hand_model, ["link_3.0_tip", "base_link"])
    for link, rgb in (("link_3.0_tip", 242 / 255), ("base_link", 1 / 255)):
        assert {m.source for m in meshes[link]} == {"material"}
        _, _, col = sample_surface_blue_noise(meshes[link], 4e-3, np.random.default_rng(0))
        assert np.allclose(col, rgb, atol=1e-5)


def test_vertex_colours_are_interpolated(tmp_path):
    box = trimesh.creation.box(extents=(0.02, 0.02, 0.02))
    box.visual.vertex_colors = np.where(box.vertices[:, :1] > 0, [255, 0, 0, 255],
                                        [0, 0, 255, 255]).astype(np.uint8)
    box.export(tmp_path / "box.ply")
    (tmp_path / "r.urdf").write_text(
        '<robot name="r"><link name="a"><visual><geometry><mesh filename="box.ply"/>'
        '</geometry></visual></link></robot>')
    meshes = load_link_meshes(parse_urdf(tmp_path / "r.urdf"))["a"]
    assert [m.source for m in meshes] == ["vertex"]
    p, _, rgb = sample_surface_blue_noise(meshes, 2e-3, np.random.default_rng(0))
    red = rgb[:, 0]
    assert np.allclose(red + rgb[:, 2], 1, atol=1e-6)  # a blend of red and blue
    assert np.allclose(red[np.abs(p[:, 0] - 0.01) < 1e-9], 1)  # the +x face is red
    assert np.allclose(red[np.abs(p[:, 0] + 0.01) < 1e-9], 0)
    assert np.allclose(red[np.abs(p[:, 0]) < 0.01], 0.5 + p[np.abs(p[:, 0]) < 0.01, 0] / 0.02,
                       atol=1e-6)  # linear across the side faces


def test_links_without_visuals_or_mesh_files_are_refused(plate, tmp_path):
    with pytest.raises(ConfigError, match="'bare' has no visual geometry in robot.urdf"):
        load_link_meshes(plate, ["bare"])
    (tmp_path / "m.urdf").write_text(
        '<robot name="m"><link name="a"><visual><geometry>'
        '<mesh filename="package://pkg/meshes/missing_finger.obj"/></geometry></visual></link>'
        '</robot>')
    with pytest.raises(AssetError, match=r"m\.urdf: <link name='a'> <visual> 0 <mesh> "
                                         r"filename='package://pkg/meshes/missing_finger\.obj'"):
        load_link_meshes(parse_urdf(tmp_path / "m.urdf"))



def test_closed_outward_needs_a_closed_outward_surface():
    """A box is closed with outward normals; turned inside out, or with a face missing, or
    split along a texture seam (duplicated vertices, still closed), the answer follows."""
    from gausstac_maniskill.splat.surface import closed_outward, colored_mesh

    box = trimesh.creation.box((0.02, 0.01, 0.03))
    assert closed_outward([colored_mesh(box)])
    inverted = box.copy()
    inverted.invert()
    assert not closed_outward([colored_mesh(inverted)])
    assert not closed_outward([colored_mesh(trimesh.Trimesh(box.vertices, box.faces[:-1]))])
    seams = trimesh.Trimesh(box.vertices[box.faces].reshape(-1, 3), np.arange(3 * len(box.faces)).reshape(-1, 3),
                            process=False)  # every face with its own vertices
    assert not seams.is_watertight and closed_outward([colored_mesh(seams)])
    two = box.copy()
    two.apply_translation([0.1, 0, 0])
    assert closed_outward([colored_mesh(box), colored_mesh(two)])
    assert not closed_outward([colored_mesh(box), colored_mesh(inverted)])
    assert not closed_outward([])
