"""Captured scenes: the similarity placement (means, covariances, SH) and the checked loader."""
import math
import warnings

import numpy as np
import pytest
import torch

from gausstac_maniskill.errors import AssetError, AssetWarning, ConfigError
from gausstac_maniskill.splat import (GaussianSet, Similarity, intrinsics_from_fov, load_capture, look_at,
                                      render, save_ply, transform_gaussians)
from gausstac_maniskill.splat.sh import sh_basis
from gausstac_maniskill.transforms import matrix_to_quat, rotation_about

# a turn of 90° about z, doubled size, shifted: p -> 2 Rz p + t
QZ90 = (math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5))
PLACE = Similarity(scale=2.0, rotation=QZ90, translation=(1.0, 2.0, 3.0))


def blob(n=200, degree=1, seed=0, spread=0.3):
    gen = torch.Generator().manual_seed(seed)
    return GaussianSet.create(torch.randn(n, 3, generator=gen) * spread,
                              torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=1),
                              torch.log(torch.rand(n, 3, generator=gen) * 0.02 + 0.005),
                              torch.randn(n, generator=gen) * 2 + 3,
                              torch.randn(n, (degree + 1) ** 2, 3, generator=gen) * 0.5)


def test_a_gaussian_at_a_known_point_lands_where_expected():
    g = GaussianSet.create([[1.0, 0.0, 0.0]], [[1.0, 0, 0, 0]], np.log([[0.01, 0.02, 0.03]]))
    h = transform_gaussians(g, PLACE)
    assert torch.allclose(h.means, torch.tensor([[1.0, 4.0, 3.0]]), atol=1e-6)  # 2·(0, 1, 0) + (1, 2, 3)
    assert torch.allclose(h.scales, torch.tensor([[0.02, 0.04, 0.06]]), atol=1e-7)  # σ·s: log σ + log 2
    R = torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert torch.allclose(h.covariances(), 4 * R @ g.covariances() @ R.T, atol=1e-9)  # s² R Σ Rᵀ
    assert torch.equal(h.opacity_logits, g.opacity_logits)


def test_similarity_matrix_inverse_and_coercion():
    M = PLACE.matrix()
    assert np.allclose(M[:3, :3], 2 * np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]]), atol=1e-12)
    assert np.allclose(PLACE.apply([[1, 0, 0]]), [[1, 4, 3]])
    back = Similarity.from_matrix(M)
    assert math.isclose(back.scale, 2.0) and np.allclose(back.rotation, QZ90) and np.allclose(back.translation, (1, 2, 3))
    assert np.allclose(PLACE.inverse().matrix() @ M, np.eye(4), atol=1e-12)
    assert Similarity.coerce(PLACE.as_dict()) == PLACE
    assert Similarity.coerce(None) == Similarity()
    assert Similarity(rotation=(2, 0, 0, 0)).rotation == (1.0, 0.0, 0.0, 0.0)  # normalised
    g = blob(degree=3)
    h = transform_gaussians(transform_gaussians(g, PLACE), PLACE.inverse())
    assert torch.allclose(h.means, g.means, atol=1e-5)
    assert torch.allclose(h.covariances(), g.covariances(), atol=1e-8)
    assert torch.allclose(h.sh, g.sh, atol=1e-4)


@pytest.mark.parametrize("bad, field", [
    (dict(scale=0.0), "scale"), (dict(scale=float("nan")), "scale"), (dict(rotation=(0, 0, 0, 0)), "rotation"),
    (dict(rotation=(1, 0, 0)), "rotation"), (dict(translation=(0, float("inf"), 0)), "translation"),
    (dict(shift=(0, 0, 0)), "shift"), (np.diag([1.0, 2.0, 1.0, 1.0]), "uniform scale"), (np.eye(3), "4x4"),
])
def test_bad_similarity_names_the_field(bad, field):
    with pytest.raises(ConfigError, match=field):
        Similarity.coerce(bad, "scene_pose")


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_sh_colour_turns_with_the_rotation(degree):
    """A rotated Gaussian seen along the rotated view direction has the colour of the
    unrotated one seen along the unrotated direction (evaluated, then rendered)."""
    rng = np.random.default_rng(degree)
    R = rotation_about(rng.normal(size=3), 1.3)
    place = Similarity(0.5, tuple(matrix_to_quat(R)), (0.3, -0.2, 0.1))
    g = blob(n=1, degree=degree, seed=degree)
    g = g.replace(means=torch.zeros(1, 3), sh=g.sh * 2)
    h = transform_gaussians(g, place)
    d = rng.normal(size=(20, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    before = np.einsum("mk,kc->mc", sh_basis(d, degree), g.sh[0].double().numpy())
    after = np.einsum("mk,kc->mc", sh_basis(d @ R.T, degree), h.sh[0].double().numpy())
    assert np.allclose(before, after, atol=1e-4)
    # the same in pictures: the camera moved by the same similarity sees the same image
    eye, up = np.array([0.0, -0.4, 0.25]), np.array([0.0, 0.0, 1.0])
    K = intrinsics_from_fov(32, 32, 0.8)[None]
    a = render(g, look_at(eye, [0, 0, 0], up)[None], K, 32, 32)
    b = render(h, look_at(place.apply(eye)[0], place.translation, R @ up)[None], K, 32, 32)
    assert a.alpha.max() > 0.5
    assert torch.allclose(a.rgb, b.rgb, atol=2e-3)
    unrotated = render(h.replace(sh=g.sh), look_at(place.apply(eye)[0], place.translation, R @ up)[None], K, 32, 32)
    assert (unrotated.rgb - a.rgb).abs().max() > 0.05  # the check above would see a missing SH rotation


def _write(tmp_path, g, name="capture.ply"):
    path = tmp_path / name
    save_ply(path, g)
    return path


def _no_asset_warnings(fn, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("error", AssetWarning)
        return fn(*args, **kwargs)


def test_load_capture_places_the_file(tmp_path):
    g = blob()
    h = _no_asset_warnings(load_capture, _write(tmp_path, g), PLACE.as_dict())
    assert torch.allclose(h.means, torch.as_tensor(PLACE.apply(g.means.double().numpy())).float(), atol=1e-6)
    assert h.sh_degree == 1 and len(h) == len(g)


def test_missing_property_and_nan_name_the_file_and_field(tmp_path):
    from numpy.lib.recfunctions import drop_fields
    from plyfile import PlyData, PlyElement

    path = _write(tmp_path, blob(n=20))
    v = PlyData.read(str(path))["vertex"].data
    cut = drop_fields(v, "scale_1", usemask=False)
    PlyData([PlyElement.describe(cut, "vertex")]).write(str(tmp_path / "noscale.ply"))
    with pytest.raises(AssetError, match=r"noscale\.ply: vertex property 'scale_1' missing"):
        load_capture(tmp_path / "noscale.ply")
    v = v.copy()
    v["opacity"][7] = np.nan
    PlyData([PlyElement.describe(v, "vertex")]).write(str(tmp_path / "nan.ply"))
    with pytest.raises(AssetError, match=r"nan\.ply: vertex property 'opacity' has non-finite values \(vertex 7\)"):
        load_capture(tmp_path / "nan.ply")
    (tmp_path / "cut.ply").write_bytes(path.read_bytes()[:-50])  # 54 of the last row's 104 bytes remain
    with pytest.raises(AssetError, match=r"cut\.ply: early end-of-file at vertex 19, property 'f_rest_4'"):
        load_capture(tmp_path / "cut.ply")


def test_too_many_gaussians_is_an_error_or_a_warning_with_the_count(tmp_path):
    path = _write(tmp_path, blob(n=150), "big.ply")
    with pytest.raises(AssetError, match=r"big\.ply: element 'vertex' holds 150 Gaussians, more than "
                                         r"max_gaussians=100"):
        load_capture(path, max_gaussians=100)
    with pytest.warns(AssetWarning, match=r"big\.ply: 150 Gaussians \(more than 100\)"):
        load_capture(path, warn_gaussians=100)


@pytest.mark.parametrize("scale, spans, hint", [(1000.0, "1.2[0-9]*e\\+03 m", "scale=0.8"),
                                               (1e-4, "0.0001[0-9]* m", "scale=0.8")])
def test_mis_scaled_capture_warns_with_the_file_and_a_scale(tmp_path, scale, spans, hint):
    g = GaussianSet.create(torch.rand(300, 3, generator=torch.Generator().manual_seed(0)) * 1.25,
                           log_scales=torch.full((300, 3), math.log(0.005)), opacity_logits=torch.full((300,), 3.0))
    path = _write(tmp_path, g, "room.ply")
    with pytest.warns(AssetWarning, match=rf"room\.ply: the placed capture spans {spans} .*{hint}"):
        load_capture(path, Similarity(scale=scale))
    _no_asset_warnings(load_capture, path)  # 1.2 m at scale 1: fine


def test_linear_scales_and_activated_opacities_warn(tmp_path):
    g = blob(n=300)
    lin = _write(tmp_path, g.replace(log_scales=torch.full_like(g.log_scales, 0.3)), "lin.ply")
    with pytest.warns(AssetWarning, match=r"lin\.ply: .*'scale_0\.\.2' must hold log standard deviations"):
        load_capture(lin)
    act = _write(tmp_path, g.replace(opacity_logits=torch.rand(300)), "act.ply")
    with pytest.warns(AssetWarning, match=r"act\.ply: every vertex property 'opacity' lies in \[0, 1\]"):
        load_capture(act)
