"""Scene lighting of Gaussians (splat.lighting + the rasterizer's shading) against Lambert's
formula written out here, and against SAPIEN's own render of a diffuse sphere."""
import math

import numpy as np
import pytest
import torch

from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.splat import (MANISKILL_DEFAULT, FramedGaussians, GaussianSet, Lighting, intrinsics_from_fov,
                                      look_at, rasterize, render, rgb_to_sh_dc, surface_normals)
from gausstac_maniskill.splat.gaussians import rotmat_to_quat

W = H = 16
ALBEDO = torch.tensor([0.6, 0.4, 0.2])
AMBIENT = (0.3, 0.2, 0.1)
E = (1.0, 0.9, 0.8)
OPACITY_LOGIT = 6.0  # peak alpha sigmoid(6) = 0.9975


def disc(normal=(0.0, 0.0, 1.0), rgb=ALBEDO, n=1):
    """``n`` copies of a flat opaque disc (σ 5 cm in plane, 1 mm along ``normal``) at the origin."""
    z = torch.nn.functional.normalize(torch.as_tensor(normal, dtype=torch.float32), dim=0)
    x = torch.linalg.cross(z, torch.tensor([0.3, 0.5, 0.8]))
    x = x / x.norm()
    R = torch.stack([x, torch.linalg.cross(z, x), z], dim=1)  # columns: disc axes
    return GaussianSet.create(torch.zeros(n, 3), rotmat_to_quat(R)[None].expand(n, 4),
                              torch.log(torch.tensor([[0.05, 0.05, 0.001]])).expand(n, 3),
                              torch.full((n,), OPACITY_LOGIT), rgb_to_sh_dc(torch.as_tensor(rgb)).reshape(1, 1, 3))


def camera(eye=(0.0, 0.0, 1.0)):
    """A camera at ``eye`` looking at the origin (the disc fills the centre pixel)."""
    up = (0.0, 1.0, 0.0) if abs(eye[0]) + abs(eye[1]) < 1e-9 else (0.0, 0.0, 1.0)
    return look_at(eye, (0.0, 0.0, 0.0), up=up)[None], intrinsics_from_fov(W, H, 0.3)[None]


def lambert(out, normal, direction, gamma=1.0):
    """Expected centre pixel of ``out`` (one Gaussian over black): its alpha there times
    ((A + E · max(0, n·l) / π) · albedo)^(1/gamma), with l = -d/|d| towards the light."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    ll = -np.asarray(direction, float) / np.linalg.norm(direction)
    light = np.asarray(AMBIENT) + np.asarray(E) * max(0.0, float(n @ ll)) / math.pi
    alpha = float(out.alpha[0, H // 2, W // 2])
    return torch.tensor(alpha * (light * ALBEDO.numpy()) ** (1.0 / gamma), dtype=torch.float32)


def centre(out):
    return out.rgb[0, H // 2, W // 2]


@pytest.mark.parametrize("direction, gamma", [
    ((0.0, 0.0, -1.0), 1.0),   # light straight onto the disc: A + E/π
    ((1.0, 1.0, -1.0), 1.0),   # oblique: A + E/(π√3)
    ((0.0, 0.0, -1.0), 2.2),   # display-encoded like SAPIEN's shaders
    ((0.0, 0.0, 1.0), 1.0),    # light from behind: ambient only
    ((1.0, 0.0, 0.0), 1.0),    # grazing: ambient only
])
def test_flat_gaussian_gets_lambert_shading(direction, gamma):
    V, K = camera()
    lighting = Lighting(AMBIENT, (direction,), (E,), gamma=gamma)
    out = render(disc(), V, K, W, H, lighting=lighting)
    assert float(out.alpha[0, H // 2, W // 2]) > 0.9
    assert torch.allclose(centre(out), lambert(out, (0, 0, 1), direction, gamma), atol=2e-4), centre(out)


@pytest.mark.parametrize("gamma", [1.0, 2.2])
def test_grey_lights_take_the_one_power_path_with_the_same_picture(gamma):
    """A grey ambient and grey lights make the kernel take one power per Gaussian (with the
    set's albedo^(1/gamma), kept per exponent): Lambert's colour all the same, and the
    picture of a light grey to within 1e-6 (three powers per Gaussian)."""
    direction = (1.0, 1.0, -1.0)
    grey = Lighting((0.25,) * 3, (direction,), ((0.9,) * 3,), gamma=gamma)
    almost = Lighting((0.25,) * 3, (direction,), ((0.9, 0.9, 0.9 + 1e-6),), gamma=gamma)
    assert grey.is_grey and not almost.is_grey and not Lighting(AMBIENT, (direction,), (E,)).is_grey
    V, K = camera()
    g = disc()
    framed = FramedGaussians.from_gaussians(g, torch.zeros(len(g), dtype=torch.int64), 1, lit=True)
    frames = torch.eye(4)[None, :3]
    for other in (2.0, gamma):  # a second exponent on the same set does not reuse the first's powers
        out = framed.render(frames, None, V, K, W, H, lighting=Lighting((0.25,) * 3, (direction,), ((0.9,) * 3,),
                                                                         gamma=other))
    light = 0.25 + 0.9 * max(0.0, float(np.array([0.0, 0.0, 1.0]) @ -np.array(direction)) / math.sqrt(3)) / math.pi
    expected = float(out.alpha[0, H // 2, W // 2]) * (light * ALBEDO) ** (1.0 / gamma)
    assert torch.allclose(centre(out), expected, atol=2e-4), centre(out)
    three = framed.render(frames, None, V, K, W, H, lighting=almost)
    assert (out.rgb - three.rgb).abs().max() < 1e-5


def test_normal_sign_does_not_matter_the_side_facing_the_camera_is_lit():
    """Normals are two-sided: a disc whose stored normal points away from the camera is lit
    like one facing it; seen from behind, the other side is the one lit (ambient only here)."""
    V, K = camera()
    lighting = Lighting(AMBIENT, ((0.0, 0.0, -1.0),), (E,), gamma=1.0)
    front = centre(render(disc((0, 0, 1)), V, K, W, H, lighting=lighting))
    flipped = centre(render(disc((0, 0, -1)), V, K, W, H, lighting=lighting))
    assert torch.allclose(front, flipped, atol=1e-6)
    Vb, Kb = camera((0.0, 0.0, -1.0))
    behind = render(disc((0, 0, 1)), Vb, Kb, W, H, lighting=lighting)
    assert torch.allclose(centre(behind), lambert(behind, (0, 0, -1), (0.0, 0.0, -1.0)), atol=2e-4)


def test_baked_colour_without_lighting_is_the_stored_colour():
    V, K = camera()
    out = render(disc(), V, K, W, H)
    assert torch.allclose(centre(out), out.alpha[0, H // 2, W // 2] * ALBEDO, atol=2e-4)


def test_normals_move_with_their_frames():
    """A rigid frame turns the normal with its rotation; a particle frame F keeps it
    perpendicular to the deformed disc (n ∝ F e_x × F e_y for a disc in the x-y plane)."""
    V, K = camera()
    direction = (0.3, -0.5, -1.0)
    lighting = Lighting(AMBIENT, (direction,), (E,), gamma=1.0)
    flat = disc((0, 0, 1))
    c = 0.6
    R = torch.tensor([[1.0, 0.0, 0.0], [0.0, math.cos(c), -math.sin(c)], [0.0, math.sin(c), math.cos(c)]])
    F = torch.tensor([[1.1, 0.3, 0.0], [-0.2, 0.9, 0.0], [0.1, 0.25, 0.8]])
    for M, n_world in ((R, R[:, 2]), (F, torch.linalg.cross(F[:, 0], F[:, 1]))):
        framed = FramedGaussians.from_gaussians(flat, torch.zeros(1, dtype=torch.int64), 1, lit=True)
        frames = torch.cat([M, torch.zeros(3, 1)], dim=1)[None]
        out = framed.render(frames, None, V, K, W, H, lighting=lighting)
        # the expected colour from the independently computed world normal, rendered unframed
        ref = rasterize(framed.means, None, None, framed.opacities, framed.sh, V, K, W, H,
                        covars=(M @ flat.covariances()[0] @ M.T)[None], normals=n_world[None], lighting=lighting)
        assert torch.allclose(out.rgb, ref.rgb, atol=1e-5)
        n = n_world.numpy()
        n = -n if n[2] < 0 else n  # the side facing the camera (at +z)
        assert torch.allclose(centre(out), lambert(out, n, direction), atol=2e-4)


def test_unlit_gaussians_keep_their_colour_next_to_lit_ones():
    """In one set, Gaussians without normals (a captured layer) are drawn as without lighting,
    bit for bit, while those with normals are shaded."""
    V, K = camera()
    lighting = Lighting(AMBIENT, ((0.0, 0.0, -1.0),), (E,))
    lit = FramedGaussians.from_gaussians(disc(), torch.zeros(1, dtype=torch.int64), 1, lit=True)
    captured = FramedGaussians.from_gaussians(disc(rgb=(0.1, 0.8, 0.3)), torch.zeros(1, dtype=torch.int64), 1)
    assert captured.normals is None
    both = FramedGaussians.cat([captured, lit])
    assert torch.equal(both.normals[0], torch.zeros(3)) and both.normals[1].norm() > 0.99
    frames = torch.eye(4)[None].repeat(2, 1, 1)
    # the lit disc moved out of the way: the captured one alone, with and without lighting
    frames[1, 0, 3] = 10.0
    a = both.render(frames, None, V, K, W, H, lighting=lighting)
    b = both.render(frames, None, V, K, W, H)
    assert torch.equal(a.rgb, b.rgb)
    frames[1, 0, 3] = 0.0
    frames[0, 0, 3] = 10.0
    a = both.render(frames, None, V, K, W, H, lighting=lighting)
    b = both.render(frames, None, V, K, W, H)
    assert (a.rgb - b.rgb).abs().max() > 0.05


def test_render_layers_are_unlit_unless_asked():
    from gausstac_maniskill.render import RigidLayer

    assert RigidLayer(disc()).framed().normals is None
    assert RigidLayer(disc(), lit=True).framed().normals.norm(dim=1).min() > 0.99


def test_surface_normals_are_the_shortest_axis_of_flat_gaussians_only():
    g = disc((1.0, 2.0, -0.5), n=1)
    n = surface_normals(g.quats, g.scales)
    assert torch.allclose(n[0].abs(), torch.nn.functional.normalize(torch.tensor([1.0, 2.0, -0.5]), dim=0).abs(),
                          atol=1e-5)
    round_blob = torch.tensor([[0.01, 0.012, 0.009]])
    assert torch.equal(surface_normals(g.quats, round_blob)[0], torch.zeros(3))
    assert surface_normals(torch.zeros(0, 4), torch.zeros(0, 3)).shape == (0, 3)


def test_lighting_checks_its_inputs():
    with pytest.raises(ConfigError, match="ambient"):
        Lighting((-0.1, 0.0, 0.0))
    with pytest.raises(ConfigError, match="zero vector"):
        Lighting(AMBIENT, ((0.0, 0.0, 0.0),), (E,))
    with pytest.raises(ConfigError, match="directions but"):
        Lighting(AMBIENT, ((0.0, 0.0, 1.0),), ())
    with pytest.raises(ConfigError, match="gamma"):
        Lighting(AMBIENT, gamma=0.0)
    V, K = camera()
    g = disc()
    with pytest.raises(ConfigError, match="needs normals"):
        rasterize(g.means, g.quats, g.scales, g.opacities, g.sh, V, K, W, H, lighting=MANISKILL_DEFAULT)
    with pytest.raises(ConfigError, match="Lighting"):
        render(g, V, K, W, H, lighting="scene")
    assert MANISKILL_DEFAULT.kernel_array().shape == (3, 6)


@pytest.mark.sapien
def test_lit_gaussian_sphere_looks_like_sapiens_diffuse_sphere():
    """SAPIEN's minimal shader (ManiSkill's camera default) on a diffuse sphere (albedo 0.5,
    no specular) under ManiSkill's default lights, against flat Gaussians sampled on the same
    sphere and lit with the lights read back from that scene: the interiors agree to a few
    grey levels (1.5 of 255 on average; the silhouettes differ: Gaussians have a soft fringe)."""
    import sapien
    import trimesh
    from mani_skill.utils import sapien_utils

    from gausstac_maniskill.splat import sapien_pose_to_opencv_extrinsic
    from gausstac_maniskill.splat.surface import gaussians_from_surface

    sapien.render.set_camera_shader_dir("minimal")
    scene = sapien.Scene()
    scene.set_ambient_light([0.3, 0.3, 0.3])
    scene.add_directional_light([1, 1, -1], [1, 1, 1])
    scene.add_directional_light([0, 0, -1], [1, 1, 1])
    radius, albedo = 0.1, 0.5
    b = scene.create_actor_builder()
    b.add_sphere_visual(radius=radius, material=sapien.render.RenderMaterial(
        base_color=[albedo, albedo, albedo, 1.0], roughness=1.0, specular=0.0, metallic=0.0))
    b.build_static()
    size, fovy = 96, 0.5
    cam = scene.add_camera("c", size, size, fovy, 0.01, 10.0)
    cam.entity.set_pose(sapien_utils.look_at(eye=[0.45, -0.35, 0.5], target=[0.0, 0.0, 0.0]).sp)
    scene.update_render()
    cam.take_picture()
    ref = torch.as_tensor(cam.get_picture("Color")[..., :3])
    if not ref.is_floating_point():  # an earlier scene in the process may leave SAPIEN writing uint8
        ref = ref.float() / 255.0
    seg = torch.as_tensor(cam.get_picture("PositionSegmentation")[..., 3].astype(np.int64)) > 0

    lighting = Lighting.from_sapien(scene)
    for field in ("ambient", "directions", "colors"):
        assert np.allclose(getattr(lighting, field), getattr(MANISKILL_DEFAULT, field), atol=1e-6), field
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=radius)
    spacing = 0.004
    pts, face = trimesh.sample.sample_surface_even(mesh, int(mesh.area / spacing ** 2), seed=0)
    g = gaussians_from_surface(pts, mesh.face_normals[face], np.full((len(pts), 3), albedo), spacing)
    V = sapien_pose_to_opencv_extrinsic(cam.entity_pose)[None]
    K = torch.as_tensor(cam.get_intrinsic_matrix(), dtype=torch.float32)[None]
    out = render(g, V, K, size, size, lighting=lighting).rgb[0]
    # interior: sphere pixels whose 5×5 neighbourhood is all sphere
    inner = -torch.nn.functional.max_pool2d(-seg.float()[None, None], 5, 1, 2)[0, 0] > 0.5
    assert inner.sum() > 500
    err = (out - ref).abs()[inner]
    assert err.mean() < 0.01 and torch.quantile(err, 0.95) < 0.025, (err.mean(), err.max())  # measured 0.006, 0.014
    baked = render(g, V, K, size, size).rgb[0]
    assert (baked - ref).abs()[inner].mean() > 2 * err.mean()  # shading is what makes them agree
