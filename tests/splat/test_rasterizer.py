"""The Taichi rasterizer against the dense torch reference, plus its edge cases."""
import math

import pytest
import torch

from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.splat import (GaussianSet, intrinsics_from_fov, look_at, rasterize,
                                      render, sapien_pose_to_opencv_extrinsic)

W, H = 64, 48
BG = (0.1, 0.2, 0.3)


def cameras():
    """Three cameras: oblique, off-centre principal point, and a wide close-up
    (Gaussians near the image border exercise the 1.3·tan(fov/2) clamp)."""
    V = torch.stack([look_at([0, -3, 0.5], [0, 0, 0]),
                     look_at([2, 1, 1.5], [0, 0.1, 0]),
                     look_at([0.2, 0.1, 1.0], [0, 0, 0], up=(0, 1, 0))])
    K = torch.stack([intrinsics_from_fov(W, H, math.radians(40)),
                     intrinsics_from_fov(W, H, math.radians(60), math.radians(70)),
                     intrinsics_from_fov(W, H, math.radians(100))])
    K[1, 0, 2] += 5.0
    K[1, 1, 2] -= 3.0
    return V, K


def compare(out, ref):
    """Largest |Δ| of rgb, depth, alpha against the dense reference (on the CPU; the
    rasterizer's outputs are on the Taichi arch's device)."""
    rgb, depth, alpha = ref
    return ((out.rgb.cpu() - rgb.cpu()).abs().max().item(), (out.depth.cpu() - depth.cpu()).abs().max().item(),
            (out.alpha.cpu() - alpha.cpu()).abs().max().item())


@pytest.mark.parametrize("sh_degree", [0, 1, 2, 3])
def test_matches_dense_reference(sh_degree, reference, scene_factory):
    g = scene_factory(300, sh_degree, seed=sh_degree)
    V, K = cameras()
    out = render(g, V, K, W, H, background=BG)
    ref = reference(g.means, g.covariances(), g.opacities, g.sh, V, K, W, H, background=BG)
    d_rgb, d_depth, d_alpha = compare(out, ref)
    print(f"SH {sh_degree}: max |Δrgb| = {d_rgb:.2e}, |Δdepth| = {d_depth:.2e} m, "
          f"|Δalpha| = {d_alpha:.2e}")  # measured: ~2e-6, ~5e-6, ~2e-6
    assert ref[2].max() > 0.5, "scene should cover the views"
    assert d_rgb <= 1e-3 and d_alpha <= 1e-4 and d_depth <= 1e-3


def test_sh_rotations_match_reference(reference, scene_factory):
    g = scene_factory(200, 3, seed=11)
    V, K = cameras()
    q = torch.nn.functional.normalize(torch.randn(len(g), 4, generator=torch.Generator()
                                                  .manual_seed(2)), dim=1)
    from gausstac_maniskill.splat import quat_to_rotmat
    R = quat_to_rotmat(q)
    out = render(g, V, K, W, H, sh_rotations=R)
    ref = reference(g.means, g.covariances(), g.opacities, g.sh, V, K, W, H, sh_rotations=R)
    plain = render(g, V, K, W, H)
    assert (plain.rgb - out.rgb).abs().max() > 1e-2  # the rotation has an effect
    assert compare(out, ref)[0] <= 1e-3


def test_saturated_scene_stops_like_reference(reference, scene_factory):
    """Dense opaque Gaussians: pixels reach T < 1e-4 and must stop identically."""
    g = scene_factory(400, 1, seed=7, spread=0.15)
    g = g.replace(opacity_logits=torch.full((len(g),), 6.0),
                  log_scales=g.log_scales + 0.7)
    V, K = cameras()
    out = render(g, V, K, W, H, background=BG)
    ref = reference(g.means, g.covariances(), g.opacities, g.sh, V, K, W, H, background=BG)
    assert (ref[2] > 1 - 1e-4 * 1.5).sum() > 100, "the stop rule must be exercised"
    d_rgb, d_depth, d_alpha = compare(out, ref)
    print(f"saturated: max |Δrgb| = {d_rgb:.2e}, |Δdepth| = {d_depth:.2e}")
    assert d_rgb <= 1e-3 and d_alpha <= 1e-4 and d_depth <= 1e-3


def test_alpha_rules_on_single_gaussian():
    """One isotropic Gaussian facing the camera: closed-form α at the centre pixel,
    the 0.99 clamp, and nothing drawn where o·exp(-d²/2) < 1/255."""
    K = torch.tensor([[[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]]])
    V = torch.eye(4)[None]
    g = GaussianSet.create([[0.0, 0.0, 2.0]], log_scales=torch.full((1, 3), math.log(0.04)),
                           opacity_logits=[10.0], sh=torch.full((1, 1, 3), 1.0))
    out = render(g, V, K, W, H)
    # pixel (31, 23) has its centre at (31.5, 23.5): offset 0.5 px in x and y from (32, 24)
    var = (100 * 0.04 / 2.0) ** 2 + 0.3  # px²
    alpha = min(0.99, torch.sigmoid(torch.tensor(10.0)).item() * math.exp(-0.5 * 0.5 / var))
    assert out.alpha[0, 23, 31].item() == pytest.approx(alpha, rel=1e-5)
    assert out.alpha.max().item() <= 0.99 + 1e-7
    colour = 0.28209479177387814 + 0.5
    assert out.rgb[0, 23, 31, 0].item() == pytest.approx(alpha * colour, rel=1e-5)
    # support radius: o exp(-r²/(2 var)) = 1/255  ->  r = sqrt(2 var ln(255 o))
    r = math.sqrt(2 * var * math.log(255 * torch.sigmoid(torch.tensor(10.0)).item()))
    row = out.alpha[0, 23]
    lit = (row > 0).nonzero().flatten()
    centres = lit.float() + 0.5 - 32
    assert centres.abs().max() <= r and (centres.abs().max() > r - 1.0)
    assert out.depth[0, 23, 31].item() == pytest.approx(alpha * 2.0, rel=1e-5)
    assert out.normalized_depth()[0, 23, 31].item() == pytest.approx(2.0, rel=1e-5)


def test_covariance_input_equals_scale_rotation(scene_factory):
    g = scene_factory(200, 2, seed=3)
    V, K = cameras()
    a = render(g, V, K, W, H, background=BG)
    b = rasterize(g.means, None, None, g.opacities, g.sh, V, K, W, H, covars=g.covariances(),
                  background=BG)
    cov = g.covariances()
    cov6 = cov[:, (0, 0, 0, 1, 1, 2), (0, 1, 2, 1, 2, 2)]
    c = rasterize(g.means, None, None, g.opacities, g.sh, V, K, W, H, covars=cov6, background=BG)
    assert (a.rgb - b.rgb).abs().max() < 1e-5
    assert torch.equal(b.rgb, c.rgb)


def _same_picture(one: torch.Tensor, batched: torch.Tensor, label=None) -> None:
    """A camera rendered alone against the same camera in a batch: equal to float32's last bits.
    Not bit for bit: torch's vectorised ops round a tensor's tail by the CPU's vector width, so
    the batched call's per-camera arithmetic may differ by an ulp (1.2e-7 in 187 of 3072 pixels on
    some hosts, bit-identical on others). A camera that saw
    another's Gaussians would differ by the colours themselves."""
    err = float((one.cpu() - batched.cpu()).abs().max())
    assert err <= 4e-7 * max(1.0, float(batched.abs().max())), (label, err)


def test_batched_cameras_equal_single_renders(scene_factory):
    g = scene_factory(150, 1, seed=4)
    V, K = cameras()
    both = render(g, V, K, W, H, background=BG)
    for c in range(V.shape[0]):
        one = render(g, V[c:c + 1], K[c:c + 1], W, H, background=BG)
        _same_picture(one.rgb[0], both.rgb[c])
        _same_picture(one.depth[0], both.depth[c])


def test_gaussian_ranges_render_each_env_as_if_alone(scene_factory):
    """Two envs' Gaussians in one set, each camera seeing its env's range and lit by its env's
    lights (different numbers of lights): every picture equals the env rendered alone, bit for
    bit (guards the batched camera's indexing; the physics of the picture is tested above)."""
    from gausstac_maniskill.splat import Lighting, surface_normals

    envs = [scene_factory(150, 0, seed=21), scene_factory(220, 0, seed=22)]
    both = GaussianSet.cat(envs)
    V, K = cameras()
    ranges = torch.tensor([[0, 150], [150, 370], [0, 150]])
    # (none grey: grey lights everywhere take a one-power path that differs by rounding)
    lights = [Lighting((0.3, 0.3, 0.3), ((1.0, 1.0, -1.0), (0.0, 0.0, -1.0)), ((1.0, 0.9, 1.0), (0.5, 0.5, 0.5))),
              Lighting((0.2, 0.25, 0.3), ((0.0, 1.0, -1.0),), ((0.9, 0.8, 0.7),), gamma=1.0),
              Lighting((0.4, 0.4, 0.45), (), ())]
    bg = torch.rand(3, H, W, 3, generator=torch.Generator().manual_seed(3))
    # (activated once: torch's vectorised exp rounds a tensor's tail differently)
    means, quats, scales, opac, sh = both.means, both.quats, both.scales, both.opacities, both.sh
    normals = surface_normals(quats, scales)
    out = rasterize(means, quats, scales, opac, sh, V, K, W, H, background=bg, lighting=lights, normals=normals,
                    gaussian_ranges=ranges)
    for c, (lo, hi) in enumerate(ranges.tolist()):
        one = rasterize(means[lo:hi], quats[lo:hi], scales[lo:hi], opac[lo:hi], sh[lo:hi], V[c:c + 1],
                        K[c:c + 1], W, H, background=bg[c:c + 1], lighting=lights[c], normals=normals[lo:hi])
        assert one.alpha.max() > 0.3, "the env should show in camera %d" % c
        for name in ("rgb", "depth", "alpha"):
            _same_picture(getattr(one, name)[0], getattr(out, name)[c], (c, name))
    with pytest.raises(ConfigError, match=r"gaussian_ranges\[1\] = \[150, 371\]"):
        render(both, V, K, W, H, gaussian_ranges=torch.tensor([[0, 150], [150, 371], [0, 1]]))
    with pytest.raises(ConfigError, match="shape \\[C, 2\\] or \\[C, 2, 2\\] \\(C = 3\\)"):
        render(both, V, K, W, H, gaussian_ranges=ranges[:2])
    with pytest.raises(ConfigError, match="sequence of C = 3"):
        render(both, V, K, W, H, lighting=lights[:2], normals=normals)


def test_two_ranges_per_camera_render_their_gaussians_alone(scene_factory):
    """[C, 2, 2] ranges: a camera sees its first range, then its second (a scene's shared
    Gaussians and one level of its hand, ``render.Detail``): every picture equals those
    Gaussians, in that order, rendered alone, to the last bits (guards the kernel's indexing)."""
    g = scene_factory(300, 1, seed=23)
    V, K = cameras()
    ranges = torch.tensor([[[0, 100], [200, 300]], [[50, 50], [120, 260]], [[0, 300], [300, 300]]])
    out = render(g, V, K, W, H, background=BG, gaussian_ranges=ranges)
    for c, ((a0, a1), (b0, b1)) in enumerate(ranges.tolist()):
        idx = torch.cat([torch.arange(a0, a1), torch.arange(b0, b1)])
        one = render(g[idx], V[c:c + 1], K[c:c + 1], W, H, background=BG)
        assert one.alpha.max() > 0.3, "the Gaussians should show in camera %d" % c
        for name in ("rgb", "depth", "alpha"):
            _same_picture(getattr(one, name)[0], getattr(out, name)[c], (c, name))
    with pytest.raises(ConfigError, match=r"gaussian_ranges\[1\] = \[\[50, 50\], \[260, 120\]\]"):
        render(g, V, K, W, H, gaussian_ranges=torch.tensor([[[0, 1], [1, 2]], [[50, 50], [260, 120]], [[0, 1]] * 2]))


def test_deterministic(scene_factory):
    g = scene_factory(300, 3, seed=5)
    V, K = cameras()
    a = render(g, V, K, W, H, background=BG)
    b = render(g, V, K, W, H, background=BG)
    for name in ("rgb", "depth", "alpha"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name


def test_keys_padded_for_the_radix_sort_render_the_same(monkeypatch, scene_factory):
    """On the CPU a key list of RADIX_PAD_FROM..RADIX_SORT_FROM entries is padded to reach
    PyTorch's radix sort (faster); the padding sorts past the last tile and is never read.
    Guards that rule: the picture is bit-equal to the unpadded sort's (18 242 keys here, in the
    padded range, checked). The padding's values are left unset (``torch.empty``); here they
    are set to draw a wide Gaussian over a whole tile, so that padding sorted into a tile shows
    (a pad of 0 fails this test, tried)."""
    from gausstac_maniskill.splat import GaussianSet
    from gausstac_maniskill.splat import rasterizer as R

    wide = GaussianSet.create(torch.zeros(1, 3), torch.tensor([[1.0, 0.0, 0.0, 0.0]]), torch.full((1, 3), 1.0),
                              torch.tensor([0.0]), torch.ones(1, 1, 3))
    g = GaussianSet.cat([wide, scene_factory(3000, 0, seed=11)])  # Gaussian 0 covers every picture
    V, K = cameras()
    empty = torch.empty
    tile_box = (15 << 4 | 15 << 12) << 32  # a value's box: columns 0..15, rows 0..15

    def unset_values_draw_gaussian_0(*args, **kwargs):
        t = empty(*args, **kwargs)
        return t.fill_(tile_box) if t.dtype == torch.int64 else t

    monkeypatch.setattr(torch, "empty", unset_values_draw_gaussian_0)
    pictures = []
    for pad_from in (10**12, 1):
        monkeypatch.setattr(R, "RADIX_PAD_FROM", pad_from)
        pictures.append(render(g, V, K, 256, 192, background=BG, timings=True))
    assert 1 <= pictures[0].stats["n_keys"] < R.RADIX_SORT_FROM, pictures[0].stats
    for name in ("rgb", "depth", "alpha"):
        assert torch.equal(getattr(pictures[0], name), getattr(pictures[1], name)), name


def test_empty_set_renders_background():
    V, K = cameras()
    out = render(GaussianSet.empty(sh_degree=2), V, K, W, H, background=BG)
    assert torch.equal(out.rgb.cpu(), torch.tensor(BG).expand(3, H, W, 3))
    assert torch.equal(out.alpha.cpu(), torch.zeros(3, H, W))
    assert torch.equal(out.depth.cpu(), torch.zeros(3, H, W))


def test_everything_behind_camera_renders_background(scene_factory):
    g = scene_factory(100, 0)
    V = look_at([0, -3, 0], [0, -6, 0])[None]  # looking away from the blob
    K = intrinsics_from_fov(W, H, 1.0)[None]
    out = render(g, V, K, W, H, background=BG)
    assert torch.equal(out.alpha.cpu(), torch.zeros(1, H, W))


def test_background_image(reference, scene_factory):
    g = scene_factory(200, 0, seed=6)
    V, K = cameras()
    bg = torch.rand(3, H, W, 3, generator=torch.Generator().manual_seed(0))
    out = render(g, V, K, W, H, background=bg)
    ref = reference(g.means, g.covariances(), g.opacities, g.sh, V, K, W, H, background=bg)
    assert compare(out, ref)[0] <= 1e-3


def test_depth_aware_compositing_occludes(reference, scene_factory):
    g = scene_factory(300, 1, seed=8)
    V, K = cameras()
    z_cam = torch.einsum("cij,nj->cni", V[:, :3, :3], g.means)[..., 2] + V[:, None, 2, 3]
    bg = torch.rand(3, H, W, 3, generator=torch.Generator().manual_seed(1))
    # left half: a surface nearer than every Gaussian; right half: a surface at the
    # median Gaussian depth (cuts the blob); a strip with no surface (inf)
    bg_depth = torch.empty(3, H, W)
    for c in range(3):
        bg_depth[c, :, : W // 2] = z_cam[c].min() - 0.01
        zs = z_cam[c].sort().values
        bg_depth[c, :, W // 2:] = 0.5 * (zs[len(zs) // 2] + zs[len(zs) // 2 + 1])  # no ties
    bg_depth[:, :4] = float("inf")
    out = render(g, V, K, W, H, background=bg, background_depth=bg_depth)
    # in front of everything: exactly the background image
    assert torch.equal(out.rgb[:, 4:, : W // 2].cpu(), bg[:, 4:, : W // 2])
    assert torch.equal(out.alpha[:, 4:, : W // 2].cpu(), torch.zeros(3, H - 4, W // 2))
    ref = reference(g.means, g.covariances(), g.opacities, g.sh, V, K, W, H, background=bg,
                    background_depth=bg_depth)
    assert compare(out, ref)[0] <= 1e-3
    free = render(g, V, K, W, H, background=bg)
    right = (slice(None), slice(4, None), slice(W // 2, None))
    assert (out.alpha[right] < free.alpha[right] - 0.05).any(), "far Gaussians must be hidden"
    assert torch.equal(out.rgb[:, :4], free.rgb[:, :4])  # no surface: unchanged
    comp = out.composited_depth(bg_depth)
    assert torch.allclose(comp[:, 4:, : W // 2].cpu(), bg_depth[:, 4:, : W // 2])


@pytest.mark.parametrize("name", ["means", "quats", "scales", "opacities", "sh", "viewmats", "Ks"])
def test_nan_inputs_raise(name, scene_factory):
    g = scene_factory(20, 1)
    V, K = cameras()
    args = dict(means=g.means.clone(), quats=g.quats.clone(), scales=g.scales.clone(),
                opacities=g.opacities.clone(), sh=g.sh.clone(), viewmats=V.clone(), Ks=K.clone())
    args[name].view(-1)[3] = float("nan")
    with pytest.raises(ConfigError, match=name):
        rasterize(width=W, height=H, **args)


@pytest.mark.parametrize("name,bad,expected", [
    ("means", torch.zeros(20, 2), r"\[N, 3\]"),
    ("quats", torch.zeros(20, 3), r"\[N, 4\]"),
    ("scales", torch.zeros(19, 3), r"\[N, 3\]"),
    ("opacities", torch.zeros(20, 1), r"\[N\]"),
    ("sh", torch.zeros(20, 5, 3), r"\[N, K, 3\]|degree"),
    ("viewmats", torch.zeros(3, 3, 4), r"\[C, 4, 4\]"),
    ("Ks", torch.zeros(2, 3, 3), r"\[C, 3, 3\]"),
])
def test_wrong_shapes_raise(name, bad, expected, scene_factory):
    g = scene_factory(20, 1)
    V, K = cameras()
    args = dict(means=g.means, quats=g.quats, scales=g.scales, opacities=g.opacities, sh=g.sh,
                viewmats=V, Ks=K)
    args[name] = bad
    with pytest.raises(ConfigError, match=expected):
        rasterize(width=W, height=H, **args)


def test_other_bad_arguments(scene_factory):
    g = scene_factory(20, 0)
    V, K = cameras()
    with pytest.raises(ConfigError, match="sigmoid"):
        rasterize(g.means, g.quats, g.scales, g.opacity_logits * 10, g.sh, V, K, W, H)
    with pytest.raises(ConfigError, match="background_depth"):
        render(g, V, K, W, H, background_depth=torch.zeros(3, W, H))
    with pytest.raises(ConfigError, match="background"):
        render(g, V, K, W, H, background=torch.zeros(2, 3))
    with pytest.raises(ConfigError, match="width"):
        render(g, V, K, 0, H)


def test_look_at_puts_target_at_principal_point():
    V = look_at([1.0, -2.0, 0.7], [0.1, 0.2, 0.3])
    p = V @ torch.tensor([0.1, 0.2, 0.3, 1.0])
    assert p[0].abs() < 1e-6 and p[1].abs() < 1e-6 and p[2] > 0
    up = V @ torch.tensor([0.1, 0.2, 0.4, 1.0])  # a point above the target: image y < 0
    assert up[1] < 0


def test_sapien_pose_conversion_closed_form():
    # SAPIEN camera at (1, 2, 3) looking along world +x (its own x axis): identity rotation
    pose = torch.eye(4)
    pose[:3, 3] = torch.tensor([1.0, 2.0, 3.0])
    V = sapien_pose_to_opencv_extrinsic(pose)
    # a point 2 m ahead, 0.5 m to the camera's left, 0.25 m up
    p = V @ torch.tensor([3.0, 2.5, 3.25, 1.0])
    assert torch.allclose(p[:3], torch.tensor([-0.5, -0.25, 2.0]))
    # the OpenGL model matrix of the same camera has axes x=-y_s, y=z_s, z=-x_s
    gl = torch.eye(4)
    gl[:3, :3] = torch.tensor([[0.0, 0, -1], [-1, 0, 0], [0, 1, 0]])
    gl[:3, 3] = pose[:3, 3]
    assert torch.allclose(sapien_pose_to_opencv_extrinsic(gl, "opengl"), V, atol=1e-6)


def test_sapien_pose_conversion_matches_sapien_camera():
    sapien = pytest.importorskip("sapien")
    try:
        scene = sapien.Scene()
        cam = scene.add_camera("c", 64, 48, 1.0, 0.01, 10.0)
    except Exception as exc:  # no Vulkan device
        pytest.skip(f"SAPIEN cannot create a camera here: {exc}")
    q = torch.nn.functional.normalize(torch.tensor([0.9, 0.1, -0.3, 0.2]), dim=0).tolist()
    cam.entity.set_pose(sapien.Pose([0.3, -0.4, 0.8], q))
    scene.update_render()
    expected = torch.as_tensor(cam.get_extrinsic_matrix(), dtype=torch.float32)
    V = sapien_pose_to_opencv_extrinsic(cam.entity.pose)
    assert torch.allclose(V[:3], expected, atol=1e-5)
    V_gl = sapien_pose_to_opencv_extrinsic(cam.get_model_matrix(), "opengl")
    assert torch.allclose(V_gl[:3], expected, atol=1e-5)
    K = torch.as_tensor(cam.get_intrinsic_matrix(), dtype=torch.float32)
    assert torch.allclose(K, intrinsics_from_fov(64, 48, 1.0), atol=1e-3)


def test_partial_edge_tiles_match_reference(reference, scene_factory):
    """An image that is not a whole number of 16×16 tiles (the last tile row and column are
    cut): the tiles' pixel masks must leave the missing pixels out and draw all others."""
    g = scene_factory(300, 1, seed=21)
    w, h = 50, 37
    V = look_at([0, -0.6, 0.0], [0, 0, 0])[None]
    K = intrinsics_from_fov(w, h, math.radians(80))[None]
    out = render(g, V, K, w, h, background=BG)
    ref = reference(g.means, g.covariances(), g.opacities, g.sh, V, K, w, h, background=BG)
    assert ref[2][:, 32:, 48:].min() > 0.5, "the scene should cover the cut corner tile"
    d_rgb, d_depth, d_alpha = compare(out, ref)
    assert d_rgb <= 1e-3 and d_alpha <= 1e-4 and d_depth <= 1e-3


def test_large_gaussians_centred_off_screen_are_kept(reference):
    """Wide Gaussians whose centres lie outside the view (beyond the 1.3·tan(fov/2) clamp)
    but whose support reaches into it: the cheap screen-bound cull must not drop them."""
    gen = torch.Generator().manual_seed(3)
    n = 40
    side = torch.where(torch.rand(n, generator=gen) < 0.5, -1.0, 1.0)
    means = torch.stack([side * (1.2 + 0.6 * torch.rand(n, generator=gen)),  # x/z about 0.6-0.9
                         torch.randn(n, generator=gen) * 0.3, torch.full((n,), 2.0)], -1)
    g = GaussianSet.create(means, torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=1),
                           torch.log(0.25 + 0.2 * torch.rand(n, 3, generator=gen)), torch.full((n,), 1.0),
                           torch.randn(n, 4, 3, generator=gen) * 0.4)
    V = torch.eye(4)[None]  # camera at the origin looking along +z
    K = intrinsics_from_fov(W, H, math.radians(40))[None]
    out = render(g, V, K, W, H, background=BG)
    ref = reference(g.means, g.covariances(), g.opacities, g.sh, V, K, W, H, background=BG)
    assert ref[2].mean() > 0.2, "the off-screen Gaussians should cover part of the view"
    assert compare(out, ref)[0] <= 1e-3


def _frames_of(g, seed):
    """Split ``g`` into 3 frames: two rigid ones and one shearing affine map (like an MPM
    particle's F); returns (local means, local covariances [N, 3, 3], frame ids, frames
    [3, 3, 4]) with M μ⁰ + t = μ and M Σ⁰ Mᵀ = Σ."""
    from gausstac_maniskill.splat import quat_to_rotmat

    gen = torch.Generator().manual_seed(seed)
    ids = torch.randint(0, 3, (len(g),), generator=gen)
    M = torch.stack([quat_to_rotmat(torch.nn.functional.normalize(torch.randn(4, generator=gen), dim=0))
                     for _ in range(3)])
    M[2] = M[2] @ torch.tensor([[1.1, 0.2, 0.0], [0.0, 0.9, 0.1], [0.05, 0.0, 1.05]])
    t = torch.randn(3, 3, generator=gen) * 0.2
    frames = torch.cat([M, t[:, :, None]], dim=-1)
    Mi = torch.linalg.inv(M.double())[ids]
    local_means = (Mi @ (g.means.double() - t[ids].double())[:, :, None])[..., 0].float()
    local_cov = (Mi @ g.covariances().double() @ Mi.transpose(1, 2)).float()
    return local_means, local_cov, ids, frames


def test_frames_pose_gaussians_like_world_coordinates(reference, scene_factory):
    """Means and covariances given in frames (rigid and affine) and posed by the kernel
    render like the same Gaussians given in world coordinates; SH rotations per frame
    equal the same rotations given per Gaussian."""
    from gausstac_maniskill.splat import quat_to_rotmat

    g = scene_factory(300, 2, seed=12)
    V, K = cameras()
    mu, cov, ids, frames = _frames_of(g, seed=1)
    R = quat_to_rotmat(torch.nn.functional.normalize(torch.randn(3, 4, generator=torch.Generator()
                                                                  .manual_seed(5)), dim=1))
    out = rasterize(mu, None, None, g.opacities, g.sh, V, K, W, H, covars=cov, frames=frames,
                    frame_ids=ids, frame_rotations=R, background=BG)
    world = rasterize(g.means, None, None, g.opacities, g.sh, V, K, W, H, covars=g.covariances(),
                      sh_rotations=R[ids], background=BG)
    ref = reference(g.means, g.covariances(), g.opacities, g.sh, V, K, W, H, sh_rotations=R[ids],
                    background=BG)
    assert compare(out, ref)[0] <= 1e-3
    for name in ("rgb", "depth", "alpha"):  # same Gaussians, the pose applied elsewhere: rounding only
        assert (getattr(out, name) - getattr(world, name)).abs().max() < 1e-4, name
    as44 = torch.cat([frames, torch.tensor([0.0, 0, 0, 1]).expand(3, 1, 4)], dim=1)
    again = rasterize(mu, None, None, g.opacities, g.sh, V, K, W, H, covars=cov, frames=as44,
                      frame_ids=ids, frame_rotations=R, background=BG)
    assert torch.equal(again.rgb, out.rgb)  # [F, 4, 4] frames are read as their top 3 rows


def test_frame_arguments_are_checked(scene_factory):
    g = scene_factory(20, 1)
    V, K = cameras()
    mu, cov, ids, frames = _frames_of(g, seed=2)
    args = (mu, None, None, g.opacities, g.sh, V, K, W, H)
    with pytest.raises(ConfigError, match="go together"):
        rasterize(*args, covars=cov, frames=frames)
    with pytest.raises(ConfigError, match=r"frame_ids must lie in \[0, 3\)"):
        rasterize(*args, covars=cov, frames=frames, frame_ids=ids + 1)
    with pytest.raises(ConfigError, match="integer tensor"):
        rasterize(*args, covars=cov, frames=frames, frame_ids=ids.float())
    with pytest.raises(ConfigError, match="frames has shape"):
        rasterize(*args, covars=cov, frames=frames[:, :, :3], frame_ids=ids)
    bad = frames.clone()
    bad[1, 0, 3] = float("nan")
    with pytest.raises(ConfigError, match="frames contains NaN"):
        rasterize(*args, covars=cov, frames=bad, frame_ids=ids)
    with pytest.raises(ConfigError, match="not both"):
        rasterize(*args, covars=cov, frames=frames, frame_ids=ids, frame_rotations=torch.eye(3).expand(3, 3, 3),
                  sh_rotations=torch.eye(3).expand(20, 3, 3))
    with pytest.raises(ConfigError, match="frame_rotations need"):
        rasterize(*args, covars=cov, frame_rotations=torch.eye(3).expand(3, 3, 3))


def test_camera_constants_follow_the_camera(scene_factory):
    """The per-camera constants are kept by the values of the camera matrices: a camera moved
    (in place, same tensor) or zoomed after a picture renders like a fresh one."""
    from gausstac_maniskill.splat import inputs as R

    g = scene_factory(120, 0, seed=8)
    V, K = cameras()
    render(g, V, K, W, H, background=BG)  # constants of V, K kept
    V2, K2 = V.clone(), K.clone()
    V[:, :3, 3] += torch.tensor([0.05, -0.02, 0.1])  # moved in place
    K[:, 0, 0] *= 1.2
    moved = render(g, V, K, W, H, background=BG)
    R._CAMERA_CACHE.clear()
    fresh = render(g, V.clone(), K.clone(), W, H, background=BG)
    assert not torch.equal(moved.rgb, render(g, V2, K2, W, H, background=BG).rgb)
    for name in ("rgb", "depth", "alpha"):
        assert torch.equal(getattr(moved, name), getattr(fresh, name)), name
    K[0, 1, 1] = -1.0
    with pytest.raises(ConfigError, match="focal lengths"):
        render(g, V, K, W, H)


def test_support_terms_kept_per_gaussian(scene_factory):
    """The opacity-aware support (ln(255 o), k = sqrt(2 ln(255 o)) + 0.1 %) is computed once per
    set; a Gaussian under 1/255 gets k = 0 (it is culled) instead of NaN."""
    from gausstac_maniskill.splat.rasterizer import SUPPORT_SLACK, _gaussian_inputs

    g = scene_factory(50, 0, seed=9)
    o = g.opacities.clone()
    o[0] = 0.5 / 255.0
    inp = _gaussian_inputs(g.means, g.quats, g.scales, o, g.sh, None, None)
    ln255o = torch.log(o.double() * 255.0)
    assert torch.equal(inp.opacity[:, 0].cpu(), o.cpu())
    assert torch.allclose(inp.opacity[:, 1].double().cpu(), ln255o.cpu(), rtol=0, atol=1e-6)
    k = torch.sqrt(2.0 * ln255o.clamp_min(0.0)) * SUPPORT_SLACK
    assert torch.allclose(inp.opacity[:, 2].double().cpu(), k.cpu(), rtol=1e-6, atol=0)
    assert inp.opacity[0, 2] == 0.0


# --------------------------------------------------------------------------- back faces
def _sphere_of_discs(n=1500, radius=0.05):
    """Flat discs on a sphere (Fibonacci points), local z = the outward normal, like the
    Gaussians :func:`gausstac_maniskill.splat.surface.gaussians_from_surface` puts on a
    closed mesh: (GaussianSet, outward normals [n, 3])."""
    from gausstac_maniskill.splat import rotmat_to_quat

    i = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1 - 2 * i / n
    phi = math.pi * (1 + 5 ** 0.5) * i
    nrm = torch.stack([(1 - z * z).sqrt() * phi.cos(), (1 - z * z).sqrt() * phi.sin(), z], 1)
    a = torch.where(nrm[:, :1].abs() < 0.9, torch.tensor([[1.0, 0, 0]], dtype=torch.float64),
                    torch.tensor([[0, 1.0, 0]], dtype=torch.float64))
    e1 = torch.nn.functional.normalize(torch.cross(a, nrm, dim=1), dim=1)
    R = torch.stack([e1, torch.cross(nrm, e1, dim=1), nrm], dim=2)  # columns: e1, e2, n
    spacing = math.sqrt(4 * math.pi * radius ** 2 / n)
    scales = torch.tensor([0.9 * spacing, 0.9 * spacing, spacing / 20]).log().expand(n, 3)
    g = GaussianSet.create((radius * nrm).float(), quats=rotmat_to_quat(R).float(), log_scales=scales,
                           opacity_logits=torch.full((n,), 4.0), sh=torch.full((n, 1, 3), 0.3))
    return g, nrm.float()


def test_back_faces_of_a_closed_surface_are_culled_without_changing_the_picture():
    """A closed sphere of discs: drawing only the discs that face the camera leaves the
    picture inside the silhouette as it was (the front side hides the back), and roughly
    halves the (Gaussian, tile) keys that are sorted and visited."""
    g, nrm = _sphere_of_discs()
    V = torch.stack([look_at([0.0, -0.25, 0.08], [0, 0, 0]), look_at([0.15, 0.12, -0.1], [0, 0, 0.01])])
    K = intrinsics_from_fov(W, H, math.radians(40)).expand(2, 3, 3)
    two = render(g, V, K, W, H, background=BG, normals=nrm)
    one = render(g, V, K, W, H, background=BG, normals=nrm, one_sided=torch.ones(len(g), dtype=torch.bool))
    assert one.stats["n_keys"] < 0.6 * two.stats["n_keys"], (one.stats, two.stats)
    # pixels 2 or more pixels inside the silhouette (the fringe, where back discs overhang the
    # sphere's outline, may change)
    outside = (two.alpha <= 0.999).float()[:, None]
    inside = torch.nn.functional.max_pool2d(outside, 5, stride=1, padding=2)[:, 0] == 0
    assert inside.sum() > 0.2 * W * H  # (the sphere fills a good part of each picture)
    assert (one.rgb - two.rgb).abs().max(-1).values[inside].max() < 2 / 255
    assert (one.normalized_depth() - two.normalized_depth()).abs()[inside].max() < 1e-3  # m
    assert (one.alpha - two.alpha).abs().mean() < 0.01


def test_one_sided_gaussian_is_culled_when_its_normal_faces_away():
    """One disc in front of the camera (camera looking along +z): with its outward normal
    along +z it faces away and is not drawn when one-sided; turned by its frame (180° about
    x: the normal moves with cof(M)) it faces the camera and is drawn; two-sided it is
    drawn either way."""
    K = torch.tensor([[[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]]])
    V = torch.eye(4)[None]
    g = GaussianSet.create([[0.0, 0.0, 0.0]], log_scales=torch.tensor([[-3.5, -3.5, -7.0]]),
                           opacity_logits=[4.0], sh=torch.full((1, 1, 3), 0.5))
    args = (g.means, g.quats, g.scales, g.opacities, g.sh, V, K, W, H)
    normal = torch.tensor([[0.0, 0.0, 1.0]])
    turn = torch.tensor([[[1.0, 0, 0, 0], [0, -1.0, 0, 0], [0, 0, -1.0, 2.0]]])  # 180° about x, then 2 m ahead
    ahead = torch.tensor([[[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 2.0]]])
    ids = torch.zeros(1, dtype=torch.int64)
    for sided, frame, drawn in ((True, ahead, False), (True, turn, True), (False, ahead, True)):
        out = rasterize(*args, normals=normal, one_sided=torch.tensor([sided]), frames=frame, frame_ids=ids)
        assert (out.alpha.max() > 0.5) == drawn, (sided, frame)
    # a one-sided Gaussian without a normal (not flat) is always drawn
    out = rasterize(*args, normals=torch.zeros(1, 3), one_sided=torch.tensor([True]), frames=ahead, frame_ids=ids)
    assert out.alpha.max() > 0.5


def test_one_sided_arguments_are_checked():
    g, nrm = _sphere_of_discs(50)
    V, K = cameras()
    args = (g.means, g.quats, g.scales, g.opacities, g.sh, V, K, W, H)
    with pytest.raises(ConfigError, match="one_sided needs normals"):
        rasterize(*args, one_sided=torch.ones(50, dtype=torch.bool))
    with pytest.raises(ConfigError, match="bool tensor"):
        rasterize(*args, normals=nrm, one_sided=torch.ones(50))
    with pytest.raises(ConfigError, match=r"one_sided has shape \[49\]"):
        rasterize(*args, normals=nrm, one_sided=torch.ones(49, dtype=torch.bool))
