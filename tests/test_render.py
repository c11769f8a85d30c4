"""RigidLayer: Gaussians outside the co-simulator (captured scenes, objects on actors) splatted
in one pass with the hand's, depth-sorted together."""
import numpy as np
import pytest
import torch

from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.mpm.gather import read_particle_frames
from gausstac_maniskill.render import RigidLayer
from gausstac_maniskill.splat import (GaussianSet, PosedGaussians, intrinsics_from_fov, look_at, pose_gaussians,
                                      rgb_to_sh_dc)
from gausstac_maniskill.transforms import make_pose

W = H = 32
CAM = look_at([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], up=(0.0, -1.0, 0.0))[None]  # looking along +z
K = intrinsics_from_fov(W, H, 0.9)[None]


def wall(z, half, rgb, spacing=0.01, sh_degree=0):
    """Flat opaque Gaussians filling the square |x|, |y| <= half at depth z."""
    xs = np.arange(-half, half + 1e-9, spacing)
    x, y = np.meshgrid(xs, xs)
    pts = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], 1)
    n = len(pts)
    sh = torch.zeros(n, (sh_degree + 1) ** 2, 3)
    sh[:, 0] = rgb_to_sh_dc(torch.tensor(rgb)).expand(n, 3)
    return GaussianSet.create(pts, log_scales=np.log([[spacing, spacing, spacing / 20]]).repeat(n, 0),
                              opacity_logits=np.full(n, 6.0), sh=sh)


def hand_and_scene(scene_z):
    """A red "hand" (a link-bound square, 1 m in front of the camera) and a blue captured
    wall (world frame, SH degree 1) at ``scene_z``, wider than the hand."""
    hand = wall(0.0, 0.1, (1.0, 0.0, 0.0))  # link frame; the link sits at z = 1
    hand_posed = pose_gaussians(hand, torch.as_tensor(make_pose([0, 0, 1.0]), dtype=torch.float32)[None])
    scene = RigidLayer(wall(scene_z, 0.6 * scene_z, (0.0, 0.0, 1.0), spacing=0.02 * scene_z, sh_degree=1))
    return hand_posed, scene


@pytest.mark.parametrize("scene_z, centre_rgb, centre_depth", [(0.5, (0, 0, 1), 0.5), (1.5, (1, 0, 0), 1.0)])
def test_scene_occludes_the_hand_only_when_in_front(scene_z, centre_rgb, centre_depth):
    hand, scene = hand_and_scene(scene_z)
    out = PosedGaussians.cat([hand, scene.posed()]).render(CAM, K, W, H)
    c = out.rgb[0, H // 2, W // 2]
    assert torch.allclose(c.cpu(), torch.tensor(centre_rgb, dtype=torch.float32), atol=0.02), c
    assert abs(float(out.normalized_depth()[0, H // 2, W // 2]) - centre_depth) < 0.01
    corner = out.rgb[0, 1, 1]  # outside the hand: the scene everywhere
    assert torch.allclose(corner.cpu(), torch.tensor([0.0, 0.0, 1.0]), atol=0.02), corner
    # sorted together, not pasted: the order of the parts does not matter
    swapped = PosedGaussians.cat([scene.posed(), hand]).render(CAM, K, W, H)
    assert torch.allclose(swapped.rgb, out.rgb, atol=1e-5)


def test_layer_follows_its_poses_and_caches_a_static_scene():
    g = wall(0.0, 0.02, (0.0, 1.0, 0.0))
    T = [make_pose([0.1, 0.2, 0.3])]
    layer = RigidLayer(g, poses=lambda: np.array(T))
    assert torch.allclose(layer.posed().means.mean(0), torch.tensor([0.1, 0.2, 0.3]), atol=1e-6)
    T[0] = make_pose([-0.1, 0.0, 0.5])  # the actor moved: posed again on the next call
    assert torch.allclose(layer.posed().means.mean(0), torch.tensor([-0.1, 0.0, 0.5]), atol=1e-6)
    static = RigidLayer(g)
    assert static.posed() is static.posed()


def test_cat_pads_sh_degrees_and_checks_batches():
    a = pose_gaussians(wall(1.0, 0.02, (1.0, 0.0, 0.0)))
    b = pose_gaussians(wall(1.0, 0.02, (1.0, 0.0, 0.0), sh_degree=3))
    both = PosedGaussians.cat([a, b])
    assert both.sh.shape == (len(a.means) + len(b.means), 16, 3)
    assert torch.equal(both.sh[: len(a.means), 1:], torch.zeros(len(a.means), 15, 3))
    batched = PosedGaussians(a.means[None], a.covars[None], a.sh_rotations[None], a.opacities, a.sh)
    with pytest.raises(ConfigError, match="batch shapes differ"):
        PosedGaussians.cat([a, batched])


def test_layer_frames_render_like_its_posed_set():
    """A layer's frames (identity for a world-space capture, its poses otherwise), posed by
    the rasterizer, give the image of its world-space set."""
    from gausstac_maniskill.render import PosedScene
    from gausstac_maniskill.splat import FramedGaussians

    g = wall(0.0, 0.1, (0.2, 0.8, 0.3), sh_degree=1)
    g = g.replace(sh=g.sh + 0.3 * torch.randn(g.sh.shape, generator=torch.Generator().manual_seed(0)))
    T = [make_pose([0.05, 0.0, 0.8], np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]))]  # 90° about z
    for layer in (RigidLayer(g.replace(means=g.means + torch.tensor([0.0, 0.0, 1.0]))),
                  RigidLayer(g, poses=lambda: np.array(T))):
        f, r = layer.frames()
        posed = PosedScene(layer.framed(), f, r)
        a = posed.render(CAM, K, W, H, background=0.1)
        b = layer.posed().render(CAM, K, W, H, background=0.1)
        assert b.alpha.max() > 0.5
        assert (a.rgb - b.rgb).abs().max() < 1e-4 and (a.depth - b.depth).abs().max() < 1e-4
        assert isinstance(layer.framed(), FramedGaussians) and layer.framed() is layer.framed()


def _pressed_scene(pad_solver: str = "mpm"):
    """An Allegro co-simulator with the hand's Gaussians, a ball (with Gaussians) pressed into
    the index pad so that its soft Gaussians deform, and a captured wall (SH degree 1) behind
    the fingertip as a layer; returns (sim, viewmats [1, 4, 4], Ks [1, 3, 3])."""
    import json

    from gausstac_maniskill.config import SolverSettings
    from gausstac_maniskill.cosim import GaussTacSim
    from gausstac_maniskill.demo import ASSET_DIR
    from gausstac_maniskill.mpm import Sphere
    from gausstac_maniskill.pose import MujocoPoseSource
    from gausstac_maniskill.render import box_gaussians
    from gausstac_maniskill.splat import load_ply
    from gausstac_maniskill.tactile import allegro_pad_specs

    src = MujocoPoseSource()
    poses = dict(zip(src.link_names, src.link_poses()[0].numpy()))
    sim = GaussTacSim(allegro_pad_specs(), poses, settings=SolverSettings(dx=2e-3), pad_solver=pad_solver)
    index = "link_3.0_tip"
    apex = poses[index] @ sim.pads[index].sensor_frame
    R = 6e-3
    ball = lambda d: make_pose(apex[:3, 3] + apex[:3, 2] * (R - d))  # noqa: E731
    sim.add_rigid_object("ball", Sphere(radius=R, pose=ball(-0.5e-3)))
    hand = load_ply(ASSET_DIR / "gaussians.ply")
    links = json.loads((ASSET_DIR / "links.json").read_text())["link_names"]
    sim.attach_gaussians(hand, links, {"ball": box_gaussians((R, R, R), 1.5e-3)})
    backdrop = wall(0.0, 0.15, (0.1, 0.3, 0.9), spacing=0.01, sh_degree=1)
    backdrop = backdrop.replace(means=backdrop.means + torch.as_tensor(apex[:3, 3] - 0.1 * apex[:3, 2],
                                                                       dtype=torch.float32),
                                sh=backdrop.sh + 0.3 * torch.randn(backdrop.sh.shape,
                                                                   generator=torch.Generator().manual_seed(2)))
    sim.add_render_layer(RigidLayer(backdrop))
    for k in range(6):
        sim.step(poses, 0.02, {"ball": ball(1.0e-3 * (k + 1) / 6)})
    view = look_at(apex[:3, 3] + 0.12 * apex[:3, 2] + np.array([0.0, 0.0, 0.04]), apex[:3, 3])
    return sim, view[None], intrinsics_from_fov(96, 80, 0.9)[None]


@pytest.fixture(scope="module")
def pressed_scene():
    return _pressed_scene()


def world_space(sim):
    """The scene's Gaussians moved in world space without frames (the reference path):
    pose_gaussians on links, objects and particles, then the layers."""
    scene = sim._scene
    x, F = sim.particles()
    link_poses = torch.as_tensor(np.array([sim._link_pose[n] for n in scene.hand_links]
                                          + [sim.world.colliders[sim._objects[n]].pose for n in scene.object_names]),
                                 dtype=torch.float32)
    return PosedGaussians.cat([pose_gaussians(scene.gaussians, link_poses, scene.binding, torch.as_tensor(x),
                                              torch.as_tensor(F)), *(layer.posed() for layer in scene.layers)])


def test_scene_frames_render_like_the_world_space_path(pressed_scene):
    """The scene posed as frames (links, object, particles, layer) renders like the same
    Gaussians moved in world space, with the index pad deformed by the ball."""
    sim, V, Kc = pressed_scene
    scene = sim._scene
    _, F = sim.particles()
    assert np.abs(F[scene.binding.particle_index.numpy()] - np.eye(3)).max() > 1e-3, "the pad should deform"
    posed = scene.posed()
    world = world_space(sim)
    assert len(posed.gaussians) == len(world.means)
    a = posed.render(V, Kc, 96, 80, background=(1.0, 1.0, 1.0))
    b = world.render(V, Kc, 96, 80, background=(1.0, 1.0, 1.0))
    assert 0.2 < (b.alpha > 0.5).float().mean() < 0.99
    for name in ("rgb", "depth", "alpha"):
        assert (getattr(a, name) - getattr(b, name)).abs().max() < 1e-4, name
    assert torch.allclose(posed.world().means.cpu(), world.means.cpu(), atol=1e-6)


def test_pads_at_equilibrium_are_drawn_deformed():
    """A pad solved at equilibrium (pad_solver="fem") is held at rest in the MPM world; the
    camera draws it from its solution, as the world-space path (sim.particles) places it."""
    sim, V, Kc = _pressed_scene("fem")
    scene = sim._scene
    rows = scene.binding.particle_index.numpy()
    x, F = sim.particles()
    assert np.abs(F[rows] - np.eye(3)).max() > 1e-3, "the pad should deform"
    frames = scene.soft_frames().cpu().numpy()
    particles, _ = scene.soft_rows()
    np.testing.assert_allclose(frames[:, :, 3], x[particles], atol=1e-6)
    np.testing.assert_allclose(frames[:, :, :3], F[particles], atol=1e-6)
    a = scene.posed().render(V, Kc, 96, 80, background=(1.0, 1.0, 1.0))
    b = world_space(sim).render(V, Kc, 96, 80, background=(1.0, 1.0, 1.0))
    for name in ("rgb", "depth", "alpha"):
        assert (getattr(a, name) - getattr(b, name)).abs().max() < 1e-4, name


def test_soft_gaussians_with_view_dependent_colour_turn_with_polar_F(pressed_scene):
    """Soft Gaussians whose SH have more than a DC term get polar(F) as their frames' SH
    rotation (it is skipped when no soft Gaussian's colour depends on the view)."""
    sim, V, Kc = pressed_scene
    scene = sim._scene
    g = scene.gaussians
    soft = scene.binding.gaussian_index
    sh = torch.zeros(len(g), 4, 3)
    sh[:, 0] = g.sh[:, 0]
    sh[soft, 1:] = torch.randn(len(soft), 3, 3, generator=torch.Generator().manual_seed(1))
    scene.gaussians = g.replace(sh=sh)
    scene._framed = None  # rebuilt from the new colours
    try:
        a = scene.posed().render(V, Kc, 96, 80)
        b = world_space(sim).render(V, Kc, 96, 80)
        assert scene._soft_rotations
        assert (a.rgb - b.rgb).abs().max() < 1e-4
    finally:
        scene.gaussians = g
        scene._framed = None
    scene.posed()
    assert not scene._soft_rotations  # the scene's own (DC-only) soft colours: no polar(F) needed


def test_particles_of_an_index_are_those_rows_of_all_particles(pressed_scene):
    """GaussTacSim.particles(index) gives the rows ``index`` of particles(), sleeping pads
    carried by their links as there, and so does the splat camera's read on the device
    (mpm.gather.read_particle_frames with the sim's carry rows)."""
    sim, _, _ = pressed_scene
    sleeping = [p for p in sim.pads if not sim.is_awake(p)]
    assert sleeping and len(sleeping) < len(sim.pads), "the scene should have awake and sleeping pads"
    link = sim.pads[sleeping[0]].spec.link
    saved = sim._link_pose[link]
    turn = make_pose([0.01, 0.0, 0.0], np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]))
    sim._link_pose[link] = turn @ saved  # a sleeping pad's link turned 90° and moved 1 cm
    try:
        x, F = sim.particles()
        g = sim.world.group(sleeping[0])
        assert np.abs(x[g.start:g.stop] - sim.world.positions(sleeping[0])).max() > 5e-3, "carried"
        idx = np.sort(np.random.default_rng(0).choice(len(x), len(x) // 3, replace=False))
        xi, Fi = sim.particles(idx)
        # the splat camera's read on the device: the same rows, carried in float32 there
        frames = read_particle_frames(sim.world, idx, sim.carry_rows(idx), sim.pad_carries()).cpu().numpy()
    finally:
        sim._link_pose[link] = saved
    assert xi.shape == (len(idx), 3) and Fi.shape == (len(idx), 3, 3)
    np.testing.assert_allclose(xi, x[idx], rtol=0, atol=1e-7)
    np.testing.assert_allclose(Fi, F[idx], rtol=0, atol=1e-7)
    assert frames.shape == (len(idx), 3, 4)
    np.testing.assert_allclose(frames[:, :, 3], xi, rtol=0, atol=1e-7)  # metres: float32 rounding
    np.testing.assert_allclose(frames[:, :, :3], Fi, rtol=0, atol=1e-6)


def test_hand_level_of_detail_follows_the_pixel_size(pressed_scene):
    """With the asset's levels (links.json ``levels``), a camera draws the coarsest level whose
    splats (in-plane σ) are no wider than its pixel at the hand, and the fine hand when its
    pixels are finer than every level's; each picture is the scene built on that level alone
    (guards the layout, the two ranges per camera and the choice; whether a level looks right
    is measured by ``bench look`` and ``tests/test_sensors.py``)."""
    from gausstac_maniskill.agents.base import load_hand_gaussians, load_hand_lod
    from gausstac_maniskill.demo import ASSET_DIR
    from gausstac_maniskill.render import SceneGaussians
    from gausstac_maniskill.splat.surface import IN_PLANE_SCALE

    sim, view, _ = pressed_scene
    hand, links = load_hand_gaussians(str(ASSET_DIR))
    fine_spacing, levels = load_hand_lod(str(ASSET_DIR))
    assert len(levels) == 2 and fine_spacing < levels[0][0] < levels[1][0]
    assert len(hand) > len(levels[0][1]) > len(levels[1][1]) > len(hand) / 3
    both = SceneGaussians(sim, hand, links, hand_lod=(fine_spacing, levels))
    alone = [SceneGaussians(sim, g, links) for g in (hand, levels[0][1], levels[1][1])]
    root = sim._link_pose[links[0]][:3, 3]
    z = float(view[0, 2, :3] @ torch.as_tensor(root, dtype=torch.float32) + view[0, 2, 3])
    s1, s2 = (IN_PLANE_SCALE * sp for sp, _ in levels)
    # pixels at the hand finer than level 1's splats, between level 1's and 2's, coarser than 2's
    pixels = (0.9 * s1, 0.5 * (s1 + s2), 1.2 * s2)
    Ks = [torch.tensor([[[z / p, 0.0, 24.0], [0.0, z / p, 20.0], [0.0, 0.0, 1.0]]]) for p in pixels]
    posed = both.posed()
    n, n_fine = len(posed.gaussians), both.n_hand
    n_rest = n - n_fine - len(both.hand_levels[0][1]) - len(both.hand_levels[1][1])
    end1 = n_fine + n_rest + len(both.hand_levels[0][1])
    expect = [[[0, n_fine + n_rest], [n_fine + n_rest] * 2],
              [[n_fine, n_fine + n_rest], [n_fine + n_rest, end1]],
              [[n_fine, n_fine + n_rest], [end1, n]]]
    for K, ranges, scene in zip(Ks, expect, alone):
        assert posed.ranges(view, K).tolist() == [ranges]
        a = posed.render(view, K, 48, 40, background=(1.0, 1.0, 1.0))
        b = scene.render(view, K, 48, 40, background=(1.0, 1.0, 1.0))
        assert float(b.alpha.max()) > 0.5, "the hand should be in the picture"
        assert (a.rgb - b.rgb).abs().max() < 1e-5 and (a.alpha - b.alpha).abs().max() < 1e-5


def test_closed_links_skip_the_hand_faces_turned_away(pressed_scene):
    """With the shipped asset's ``closed_links`` the hand's Gaussians are one-sided: the pressed
    fingertip's picture keeps its colour and depth away from the outlines (the nearer side
    hides the far one), with fewer (Gaussian, tile) keys. Only the hand's Gaussians are
    one-sided, and not on the links that carry a pad (their surface is open where the pad
    replaces it): the ball's, the pads' and the layer's are always drawn. Whether the outlines
    get closer to SAPIEN's is measured by ``bench look``."""
    from gausstac_maniskill.agents.base import load_hand_closed_links
    from gausstac_maniskill.demo import ASSET_DIR
    from gausstac_maniskill.render import SceneGaussians

    sim, view, Ks = pressed_scene
    hand, links = sim._scene.gaussians[torch.arange(sim._scene.n_hand)], sim._scene.hand_links
    closed = load_hand_closed_links(str(ASSET_DIR))
    one = SceneGaussians(sim, hand, links, closed_links=closed)
    two = SceneGaussians(sim, hand, links)
    sided = one.framed().one_sided
    assert two.framed().one_sided is None
    padded = torch.isin(hand.link_id, torch.tensor([links.index(p.spec.link) for p in sim.pads.values()]))
    assert padded.any() and torch.equal(sided[:one.n_hand], ~padded) and not sided[one.n_hand:].any()
    wide = look_at([0.25, -0.2, 0.25], sim._link_pose[links[0]][:3, 3])[None]  # the whole hand
    for v in (view, wide):
        a = one.render(v, Ks, 64, 48, background=(1.0, 1.0, 1.0), timings=True)
        b = two.render(v, Ks, 64, 48, background=(1.0, 1.0, 1.0), timings=True)
        assert a.stats["n_keys"] < 0.8 * b.stats["n_keys"], (a.stats, b.stats)
        outside = (b.alpha <= 0.999).float()[:, None]
        inside = torch.nn.functional.max_pool2d(outside, 5, stride=1, padding=2)[:, 0] == 0
        assert inside.sum() > 100
        # no hole: a culled surface that was not hidden would show the white background
        # (colour) or the far side, a finger's width deeper (depth)
        assert (a.alpha - b.alpha).abs()[inside].max() < 0.01
        assert (a.rgb - b.rgb).abs().max(-1).values[inside].max() < 0.02
        dz = (a.normalized_depth() - b.normalized_depth()).abs()[inside]  # m
        # (where grazing front discs leave gaps, the far side's discs had a small weight)
        assert dz.mean() < 5e-4 and dz.max() < 1e-2, (dz.mean(), dz.max())
    with pytest.raises(ConfigError, match="not among the hand links"):
        SceneGaussians(sim, hand, links, closed_links=["no_such_link"])


def test_hand_levels_of_detail_are_checked(pressed_scene):
    """A ``hand_lod`` in a three-item form, or with levels out of order, is a ConfigError
    that says the expected form (not a TypeError from inside the scene)."""
    from gausstac_maniskill.agents.base import load_hand_gaussians, load_hand_lod
    from gausstac_maniskill.demo import ASSET_DIR
    from gausstac_maniskill.errors import ConfigError
    from gausstac_maniskill.render import SceneGaussians

    sim, _, _ = pressed_scene
    hand, links = load_hand_gaussians(str(ASSET_DIR))
    fine, levels = load_hand_lod(str(ASSET_DIR))
    with pytest.raises(ConfigError, match="as splat.asset.load_hand_lod returns it"):
        SceneGaussians(sim, hand, links, hand_lod=(fine, levels[1][0], levels[1][1]))
    with pytest.raises(ConfigError, match="grow from level to level"):
        SceneGaussians(sim, hand, links, hand_lod=(fine, levels[::-1]))
