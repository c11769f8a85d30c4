"""BatchedCosim: three Allegro scenes in one MPM world against each scene alone (CPU).

Guards the batched co-simulator's correctness: envs with different hand poses and
contacts, overlapping in space, give the maps and wrenches each scene gives alone when
stepped with the same substeps (the batch takes the largest any env needs).
"""
import numpy as np
import pytest
import torch

from gausstac_maniskill.batch import BatchedCosim
from gausstac_maniskill.config import PadSolverSettings, SolverSettings
from gausstac_maniskill.cosim import GaussTacSim
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.mpm import Sphere
from gausstac_maniskill.pose import MujocoPoseSource
from gausstac_maniskill.tactile import allegro_pad_specs, readout
from gausstac_maniskill.transforms import make_pose

INDEX = "link_3.0_tip"
R = 6e-3
STEPS, DT = 6, 0.02
# Float32 rounding alone moves a scene's maps by this share of their largest value: a static
# block 5 cm from the hand, which touches nothing and only widens the grid box (so the P2G
# sums run in another order), changes the index pad's frictionless press by 1.1e-5 (depth),
# 8.5e-4 (shear: its tangential motion is weakly held) and 3.0e-5 (force). The
# batch must agree with each scene alone to within a small multiple of that.
ROUNDING = {"depth": 1e-4, "shear": 2e-3, "force": 1e-4, "pressure": 1e-4}


def _rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def setup():
    src = MujocoPoseSource()
    names = [s.link for s in allegro_pad_specs()]
    base = src.link_poses(names)[0].double().numpy()  # [L, 4, 4]
    # env 0: the hand as loaded; env 1: moved 1 mm and turned 0.2 rad (overlapping env 0),
    # pressed deeper, with friction; env 2: its ball far away (every pad asleep)
    moves = [np.eye(4), make_pose([0.001, 0.0, 0.0], _rot_z(0.2)), make_pose([0.0, 0.0005, 0.0])]
    poses = np.stack([M @ base for M in moves])  # [B, L, 4, 4]
    i = names.index(INDEX)
    settings = SolverSettings(dx=1.5e-3)
    S = GaussTacSim(allegro_pad_specs(), dict(zip(names, base)), settings=settings).pads[INDEX].sensor_frame
    envs = []  # per env: the ball's centre at step k (k = -1: 0.5 mm clear of the pad), friction
    for b, (depth, mu) in enumerate([(0.6e-3, 0.0), (0.9e-3, 0.5), (None, 0.0)]):
        W = poses[b, i] @ S
        if depth is None:
            centre = lambda k, W=W: make_pose(W[:3, 3] + W[:3, 2] * 0.05)  # noqa: E731
        else:
            centre = lambda k, W=W, d=depth: make_pose(  # noqa: E731
                W[:3, 3] + W[:3, 2] * (R + 0.5e-3 - (d + 0.5e-3) * min(1.0, (k + 1) / 4)))
        envs.append((centre, mu))
    return names, poses, settings, envs


def _balls(envs):
    return [Sphere(radius=R, pose=centre(-1), friction=mu) for centre, mu in envs]


def test_batched_envs_match_each_scene_alone(setup, monkeypatch):
    names, poses, settings, envs = setup
    batch = BatchedCosim(allegro_pad_specs(), names, torch.as_tensor(poses), settings=settings,
                         pad_settings=PadSolverSettings(solver="mpm"))
    batch.add_rigid_object("ball", _balls(envs))
    substeps = []
    for k in range(STEPS):
        obj = {"ball": np.stack([centre(k) for centre, _ in envs])}
        maps = batch.step(torch.as_tensor(poses), DT, obj)
        substeps.append(batch.world.last_step.substeps)
    assert maps[INDEX]["force"].shape[0] == 3 and maps[INDEX]["shear"].shape[-1] == 2
    for b, (centre, mu) in enumerate(envs):
        alone = GaussTacSim(allegro_pad_specs(), dict(zip(names, poses[b])), settings=settings,
                            pad_settings=PadSolverSettings(solver="mpm"))
        alone.add_rigid_object("ball", Sphere(radius=R, pose=centre(-1), friction=mu))
        for k in range(STEPS):
            alone.begin_step(dict(zip(names, poses[b])), {"ball": centre(k)})
            alone.world.step(DT, min_substeps=substeps[k])
            alone.end_step()
            info = alone.world.last_step
            assert info.substeps == substeps[k] or info.active_particles == 0  # asleep: nothing to step
        a = alone.tactile()
        for pad in batch.pad_names:
            assert batch.scenes[b].is_awake(pad) == alone.is_awake(pad), (b, pad)
            for key in ("depth", "shear", "force", "pressure"):
                ref = a[pad][key]
                tol = ROUNDING[key] * float(ref.abs().max()) + 1e-12
                np.testing.assert_allclose(maps[pad][key][b].cpu().numpy(), ref.cpu().numpy(), rtol=0, atol=tol,
                                           err_msg=f"env {b} pad {pad} {key}")
        w_alone = np.concatenate(alone.object_wrench("ball"))
        np.testing.assert_allclose(batch.object_wrench("ball")[b], w_alone, rtol=0,
                                   atol=1e-4 * np.abs(w_alone).max() + 1e-12)
        pairs, pairs_alone = batch.link_contacts(INDEX)[b], alone.link_contacts(INDEX)
        assert pairs.keys() == pairs_alone.keys() == ({"ball"} if b < 2 else set())
        for name, row in pairs_alone.items():
            np.testing.assert_allclose(pairs[name], row, rtol=0, atol=1e-4 * np.abs(row).max())
    # the pair sums hold, per link, its own env's colliders (one each) and the other field:
    # linear in the env count, not links × all colliders
    assert batch.world._pair_impulse.shape == (len(batch.world.link_names), 2, 7)
    # real, different contacts in envs 0 and 1; none in env 2
    f = [float(maps[INDEX]["force"][b].sum()) for b in range(3)]
    assert f[0] > 0.05 and f[1] > 1.3 * f[0] and f[2] == 0.0
    assert not any(batch.scenes[2].is_awake(p) for p in batch.pad_names)
    # the batch's read is one launch for every env and pad, and gives each env what its scene
    # reads of itself in the shared world, bit for bit (the same sums)
    launches = []
    monkeypatch.setattr(readout, "taxel_maps", lambda *a, _f=readout.taxel_maps: launches.append(_f(*a)))
    again = batch.tactile()
    assert len(launches) == 1
    for b, scene in enumerate(batch.scenes):
        own = scene.readout().maps()
        for pad in batch.pad_names:
            for key in own[pad]:
                assert torch.equal(again[pad][key][b], own[pad][key][0]), (b, pad, key)


def test_bad_batch_input_is_named(setup):
    names, poses, settings, _ = setup
    with pytest.raises(ConfigError, match=r"link_poses must have shape \[B, 4, 4, 4\]"):
        BatchedCosim(allegro_pad_specs(), names, poses[:, :2], settings=settings,
                     pad_settings=PadSolverSettings(solver="mpm"))
    batch = BatchedCosim(allegro_pad_specs(), names, poses[:1], settings=settings,
                         pad_settings=PadSolverSettings(solver="mpm"))
    bad = poses[:1].copy()
    bad[0, 0, 0, 3] = np.nan
    with pytest.raises(ConfigError, match="link_poses contains NaN"):
        batch.step(bad, DT)
    with pytest.raises(ConfigError, match="step the batch"):
        batch.scenes[0].step(dict(zip(names, poses[0])), DT)


def test_env_state_moves_between_the_batch_and_the_scene_alone(setup):
    """One env's state (GaussTacSim.flat_state) from a batch loads into the scene alone, and
    the whole batch restored from its envs' states replays bit for bit (on the CPU; on CUDA
    the scatter's atomic adds land in no fixed order, so to float32 rounding)."""
    names, poses, settings, envs = setup
    batch = BatchedCosim(allegro_pad_specs(), names, poses, settings=settings,
                         pad_settings=PadSolverSettings(solver="mpm"))
    batch.add_rigid_object("ball", _balls(envs))

    def step(k):
        maps = batch.step(poses, DT, {"ball": np.stack([centre(k) for centre, _ in envs])})
        return {p: {key: m.clone() for key, m in v.items()} for p, v in maps.items()}

    for k in range(3):
        step(k)
    saved = [s.flat_state() for s in batch.scenes]
    after = step(3)
    substeps = batch.world.last_step.substeps
    # the batch restored env by env replays the step exactly
    for scene, st in zip(batch.scenes, saved):
        scene.load_flat_state(st)
    again = step(3)
    for pad in batch.pad_names:
        for key in after[pad]:
            if not batch.world.bit_reproducible:  # CUDA's atomic scatter
                tol = ROUNDING[key] * float(after[pad][key].abs().max()) + 1e-12
                torch.testing.assert_close(again[pad][key], after[pad][key], rtol=0, atol=tol, msg=f"{pad} {key}")
            else:
                assert torch.equal(after[pad][key], again[pad][key]), (pad, key)
    # env 1's state in the scene alone: it steps on like env 1 of the batch
    centre, mu = envs[1]
    alone = GaussTacSim(allegro_pad_specs(), dict(zip(names, poses[1])), settings=settings,
                        pad_settings=PadSolverSettings(solver="mpm"))
    alone.add_rigid_object("ball", Sphere(radius=R, pose=centre(-1), friction=mu))
    alone.load_flat_state(saved[1])
    alone.begin_step(dict(zip(names, poses[1])), {"ball": centre(3)})
    alone.world.step(DT, min_substeps=substeps)
    alone.end_step()
    a = alone.tactile()
    assert float(a[INDEX]["force"].sum()) > 0.1
    for pad in batch.pad_names:
        for key in ("depth", "shear", "force", "pressure"):
            ref = a[pad][key]
            tol = ROUNDING[key] * float(ref.abs().max()) + 1e-12
            np.testing.assert_allclose(after[pad][key][1].cpu().numpy(), ref.cpu().numpy(), rtol=0, atol=tol,
                                       err_msg=f"pad {pad} {key}")


def test_batch_renders_every_env_in_one_call(setup, monkeypatch):
    """BatchedCosim.render: every env's splat scene in one rasterizer call gives each camera
    the picture of its env's scene rendered alone, bit for bit (guards the batched camera's
    indexing, posing and lights; the picture's own accuracy is tested in tests/splat)."""
    import json

    from gausstac_maniskill.demo import ASSET_DIR
    from gausstac_maniskill.render import RigidLayer, box_gaussians
    from gausstac_maniskill.splat import MANISKILL_DEFAULT, GaussianSet, intrinsics_from_fov, load_ply, look_at
    from gausstac_maniskill.splat import rasterizer

    names, poses, settings, envs = setup
    batch = BatchedCosim(allegro_pad_specs(), names, poses, settings=settings,
                         pad_settings=PadSolverSettings(solver="mpm"))
    batch.add_rigid_object("ball", _balls(envs))
    hand = load_ply(ASSET_DIR / "gaussians.ply")
    links = json.loads((ASSET_DIR / "links.json").read_text())["link_names"]
    for b in (0, 1):  # env 2 has no Gaussians: its camera sees the background
        batch.scenes[b].attach_gaussians(hand, links, {"ball": box_gaussians((R, R, R), 1.5e-3)})
    wall = GaussianSet.create(torch.tensor([[0.0, 0.0, 0.0]]) + torch.as_tensor(poses[1, 0, :3, 3]).float(),
                              torch.tensor([[1.0, 0.0, 0.0, 0.0]]), torch.log(torch.tensor([[0.02, 0.02, 1e-3]])),
                              torch.tensor([3.0]), torch.tensor([[[0.5, -0.5, 0.2]]]))
    batch.scenes[1].add_render_layer(RigidLayer(wall))  # env 1 has one more Gaussian than env 0
    full = dict(zip(links, np.broadcast_to(np.eye(4), (len(links), 4, 4))))
    i = names.index(INDEX)
    for k in range(3):
        batch.step(poses, DT, {"ball": np.stack([centre(k) for centre, _ in envs])})
        for b in (0, 1):  # every hand link's pose for the renderer (the batch only had the pad links)
            scene = batch.scenes[b]
            scene._link_pose.update({n: T for n, T in full.items() if n not in scene._link_pose})
    width, height = 64, 48
    tips = [poses[b, i, :3, 3] for b in (0, 1, 2, 0)]
    V = torch.stack([look_at(t + np.array([0.03, -0.05, 0.04 + 0.01 * c]), t) for c, t in enumerate(tips)])
    K = intrinsics_from_fov(width, height, 0.8)[None].expand(4, 3, 3)
    bg = torch.rand(4, height, width, 3, generator=torch.Generator().manual_seed(0))
    launches = []
    monkeypatch.setattr(rasterizer, "_project", lambda *a, _f=rasterizer._project: launches.append(_f(*a)))
    out = batch.render(V, K, width, height, camera_env=[0, 1, 2, 0], background=bg, lighting=MANISKILL_DEFAULT)
    assert len(launches) == 1
    assert torch.equal(out.rgb[2], bg[2].to(out.rgb.device)) and float(out.alpha[2].max()) == 0.0
    for c, b in enumerate((0, 1, 2, 0)):
        if b == 2:
            continue
        alone = batch.scenes[b].render(V[c:c + 1], K[c:c + 1], width, height, background=bg[c:c + 1],
                                       lighting=MANISKILL_DEFAULT)
        assert float(alone.alpha[0].max()) > 0.9, "the hand should fill part of camera %d" % c
        for key in ("rgb", "depth", "alpha"):
            assert torch.equal(out.__dict__[key][c], alone.__dict__[key][0]), (c, key)
    with pytest.raises(ConfigError, match=r"camera_env must hold one env index in \[0, 3\)"):
        batch.render(V, K, width, height, camera_env=[0, 1, 3, 0])


def test_batched_pads_at_equilibrium_read_what_each_scene_alone_reads(setup):
    """pad_solver="fem" in a batch: each env solves its own pads (one body per pad for all
    envs), its maps are those of the same scene alone, an env with nothing near reads zeros,
    and an env's flat state moves into the scene alone."""
    names, poses, settings, _ = setup
    settings = SolverSettings(dx=2e-3)
    specs = [s for s in allegro_pad_specs() if s.link == INDEX]
    with pytest.warns(Warning):  # 2 mm: a coarse pad, for speed
        batch = BatchedCosim(specs, names, poses[:2], settings=settings, pad_settings=PadSolverSettings(solver="fem"))
        alone = GaussTacSim(specs, dict(zip(names, poses[0])), settings=settings,
                            pad_settings=PadSolverSettings(solver="fem"))
    apex = poses[0][names.index(INDEX)] @ alone.pads[INDEX].sensor_frame
    ball = lambda d: make_pose(apex[:3, 3] + apex[:3, 2] * (R - d))  # noqa: E731
    far = make_pose(apex[:3, 3] + [0.0, 0.0, 0.3])
    batch.add_rigid_object("ball", [Sphere(radius=R, pose=ball(-0.5e-3), friction=0.5),
                                    Sphere(radius=R, pose=far, friction=0.5)])
    alone.add_rigid_object("ball", Sphere(radius=R, pose=ball(-0.5e-3), friction=0.5))
    for k in range(3):
        d = 0.8e-3 * (k + 1) / 3
        maps = batch.step(poses[:2], DT, {"ball": np.stack([ball(d), far])})[INDEX]
        ref = alone.step(dict(zip(names, poses[0])), DT, {"ball": ball(d)})[INDEX]
    assert batch.scenes[1].solvers["fem"].pads[INDEX].body is batch.scenes[0].solvers["fem"].pads[INDEX].body
    assert float(ref["force"].sum()) > 0.05
    for key in ("depth", "shear", "force", "pressure"):
        np.testing.assert_array_equal(maps[key][0].cpu().numpy(), ref[key].cpu().numpy())
        assert float(maps[key][1].abs().max()) == 0.0
    np.testing.assert_array_equal(batch.scenes[0].object_wrench("ball")[0], alone.object_wrench("ball")[0])
    flat = batch.scenes[0].flat_state()
    alone.load_flat_state(flat)
    np.testing.assert_array_equal(alone.flat_state()["fem0_force"], flat["fem0_force"])


def test_batched_pads_at_equilibrium_meet_their_own_envs_soft_object(setup):
    """The default pads (pad_solver="auto": at equilibrium) and a soft block in every env of a
    batch: each env's pad surface is a collider of its own env, loaded by its own block. Env 0's
    index pad pressed 0.8 mm into its block reads what the same scene alone reads (the world's
    sums run over both envs: float32 rounding apart); env 1's block, 5 cm off, leaves its pad at
    zero."""
    from gausstac_maniskill.config import Material
    from gausstac_maniskill.mpm import box_particles

    names, poses, _, _ = setup
    settings = SolverSettings(dx=2e-3)
    specs = [s for s in allegro_pad_specs() if s.link == INDEX]
    i = names.index(INDEX)
    with pytest.warns(Warning):  # 2 mm: a coarse pad, for speed
        batch = BatchedCosim(specs, names, poses[:2], settings=settings)
        alone = GaussTacSim(specs, dict(zip(names, poses[0])), settings=settings)
    foam = Material(E=2e4, nu=0.3, density=1000.0)
    h = settings.particle_spacing
    local = box_particles(np.array([-4e-3, -4e-3, 0.0]), np.array([4e-3, 4e-3, 4e-3]), h)
    for b, scene in enumerate([*batch.scenes, alone]):
        W = poses[b if b < 2 else 0][i] @ scene.pads[INDEX].sensor_frame
        base = W[:3, 3] + W[:3, 2] * (0.3e-3 + (0.05 if b == 1 else 0.0))
        scene.add_link("table", np.eye(4))
        scene.add_soft_object("block", local @ W[:3, :3].T + base, foam, link="table", kinematic=local[:, 2] > 3e-3)
        assert scene.pad_solver == "fem"
    W0 = poses[0][i] @ alone.pads[INDEX].sensor_frame
    for k in range(3):
        P = poses[:2].copy()
        P[:, i] = make_pose(W0[:3, 2] * 0.8e-3 * (k + 1) / 3) @ P[:, i]  # the pad link towards its block
        maps = batch.step(P, DT)[INDEX]
        ref = alone.step(dict(zip(names, P[0])), DT)[INDEX]
        assert alone.world.last_step.substeps == batch.world.last_step.substeps
    assert float(ref["force"].sum()) > 0.05
    for key in ("depth", "shear", "force", "pressure"):
        tol = 1e-3 * float(ref[key].abs().max()) + 1e-12
        np.testing.assert_allclose(maps[key][0].cpu().numpy(), ref[key].cpu().numpy(), rtol=0, atol=tol, err_msg=key)
        assert float(maps[key][1].abs().max()) == 0.0
