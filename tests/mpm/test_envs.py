"""Batched MPM worlds: B envs (independent scenes) in one world step in the same launches.

What these tests guard: envs that overlap in space do not interact (grid copies and
collider filtering per env), a batched env steps like the same scene alone (to float
rounding; bit-equal where the summation order is the same), and the number of kernel
launches per step does not grow with the number of envs.
"""
import numpy as np
import pytest

from gausstac_maniskill.config import Material, SolverSettings
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.mpm import MPMWorld, box_particles
from gausstac_maniskill.mpm import kernels as K
from gausstac_maniskill.geometry.colliders import Sphere
from gausstac_maniskill.transforms import make_pose

SETTINGS = dict(dx=1e-3, gravity=(0.0, 0.0, -9.81), mass_scaling=100.0, max_substeps=2000)
MAT = Material(E=2e5, nu=0.4, density=1100.0)

# per env: link pose (yaw [rad], xyz [m]), sphere centre above the pad and its push [m]
# per step, link velocity [m/s]. Env 2 never touches its sphere. All three pads overlap in
# space: only the env index keeps them apart.
SCENES = [
    dict(yaw=0.0, shift=(0.0, 0.0, 0.0), sphere=(0.0, 0.0, 0.0034), push=4e-4, v=(0.0, 0.0, 0.0)),
    dict(yaw=0.3, shift=(0.001, -0.0005, 0.0), sphere=(0.0015, 0.001, 0.0034), push=6e-4, v=(0.02, 0.0, 0.0)),
    dict(yaw=-0.2, shift=(-0.0005, 0.0, 0.0005), sphere=(0.0, 0.0, 0.02), push=0.0, v=(0.0, 0.01, 0.0)),
]


def _yaw(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _link_pose(sc, t):
    return make_pose(np.asarray(sc["shift"]) + t * np.asarray(sc["v"]), _yaw(sc["yaw"]))


def _add_scene(world, sc, env):
    """A 8 x 8 x 4 mm block pad on link ``base{env}`` and a 3 mm sphere above it."""
    T = _link_pose(sc, 0.0)
    world.add_link(f"base{env}", T, env=env)
    h = world.settings.particle_spacing
    pts = box_particles([-0.004, -0.004, -0.004], [0.004, 0.004, 0.0], h)
    world.add_group(f"pad{env}", pts @ T[:3, :3].T + T[:3, 3], MAT, link=f"base{env}",
                    kinematic=pts[:, 2] < -0.003)
    return world.add_collider(Sphere(radius=0.003, pose=make_pose(sc["sphere"]), friction=0.5), env=env)


def _drive(world, scenes, envs, colliders, step, dt):
    for sc, e, c in zip(scenes, envs, colliders):
        world.set_link_pose(f"base{e}", _link_pose(sc, (step + 1) * dt))
        world.set_collider_pose(c, make_pose(np.asarray(sc["sphere"]) - [0.0, 0.0, sc["push"] * (step + 1)]))


def _run(scenes, steps, dt, substeps=None):
    """One world holding ``scenes`` as envs 0..B-1; returns it and the substeps of every step."""
    world = MPMWorld(SolverSettings(**SETTINGS))
    cols = [_add_scene(world, sc, e) for e, sc in enumerate(scenes)]
    taken = []
    for k in range(steps):
        _drive(world, scenes, range(len(scenes)), cols, k, dt)
        info = world.step(dt, min_substeps=substeps[k] if substeps else 1)
        taken.append(info.substeps)
    return world, cols, taken


def _readout(world, env, col):
    g = f"pad{env}"
    return dict(x=world.positions(g), F=world.deformation_gradients(g), f=world.contact_forces(g),
                wrench=np.concatenate(world.collider_wrench(col)), link=np.concatenate(world.link_wrench(f"base{env}")))


def _assert_rounding_apart(a, b, e):
    """Env ``e`` of a batch (b) against its scene alone (a), to float32 rounding: ~10 ulp at
    4 mm in position (the stencil is taken from each box's own origin, or on CUDA the atomic
    sums land in another order)."""
    np.testing.assert_allclose(b["x"], a["x"], rtol=0, atol=3e-9, err_msg=f"env {e} positions")
    np.testing.assert_allclose(b["F"], a["F"], rtol=0, atol=2e-5, err_msg=f"env {e} F")
    scale = max(np.abs(a["wrench"][:3]).max(), 1e-6)
    np.testing.assert_allclose(b["wrench"], a["wrench"], rtol=0, atol=1e-4 * scale, err_msg=f"env {e} wrench")
    np.testing.assert_allclose(b["link"], a["link"], rtol=0, atol=1e-4 * scale, err_msg=f"env {e} link")


def test_batched_envs_step_like_each_scene_alone():
    dt, steps = 4e-3, 4
    batch, cols, substeps = _run(SCENES, steps, dt)
    assert batch.num_envs == 3
    for e, sc in enumerate(SCENES):
        alone, acol, taken = _run([sc], steps, dt, substeps)
        assert taken == substeps
        _assert_rounding_apart(_readout(alone, 0, acol[0]), _readout(batch, e, cols[e]), e)
    # the scenes are different and the contacts real: the check is not comparing zeros
    f = [np.abs(np.concatenate(batch.collider_wrench(c))[2]) for c in cols]
    assert f[0] > 1e-3 and f[1] > 1e-3 and f[2] == 0.0
    assert abs(f[0] - f[1]) > 0.1 * f[0]


def test_identical_envs_are_bit_equal_to_the_scene_alone():
    """Copies of one scene share the box and the slab order: the same sums in the same order
    on the CPU. On CUDA the scatter's atomic adds land in no fixed order (runs can differ in the
    last bit of x), so there only float32 rounding is promised."""
    dt, steps = 4e-3, 3
    sc = SCENES[1]
    batch, cols, substeps = _run([sc, sc, sc], steps, dt)
    alone, acol, _ = _run([sc], steps, dt, substeps)
    a = _readout(alone, 0, acol[0])
    for e in range(3):
        b = _readout(batch, e, cols[e])
        if not batch.bit_reproducible:  # CUDA's atomic scatter
            _assert_rounding_apart(a, b, e)
            continue
        for k in a:
            assert np.array_equal(a[k], b[k]), f"env {e}: {k} differs"


def test_launches_per_step_do_not_grow_with_envs(monkeypatch):
    counts = {}
    for name in ("prepare", "advance", "fbar_update", "reduce_contact", "follow_links", "reset_contact",
                 "chunk_health"):
        kernel = getattr(K, name)

        def counted(*args, _k=kernel, _n=name, **kwargs):
            counts[_n] = counts.get(_n, 0) + 1
            return _k(*args, **kwargs)

        monkeypatch.setattr(K, name, counted)
    dt = 4e-3
    _run(SCENES, 2, dt)  # compile outside the count
    counts.clear()
    three, _, sub3 = _run(SCENES, 2, dt)
    n_three = dict(counts)
    most = {}  # per kernel, the most launches any env alone needs (a kernel runs if any env needs it)
    for sc in SCENES:
        counts.clear()
        _, _, sub1 = _run([sc], 2, dt, sub3)  # the same substeps as the batch
        assert sub1 == sub3
        most = {k: max(most.get(k, 0), counts.get(k, 0)) for k in set(most) | set(counts)}
    assert n_three == most, f"launches with 3 envs {n_three} vs one env {most}"
    assert n_three["advance"] == sum(sub3)


def test_env_indices_are_checked():
    world = MPMWorld(SolverSettings(dx=1e-3, mass_scaling=1.0, max_substeps=2000))
    world.add_link("a", np.eye(4), env=1)
    pts = box_particles([0, 0, 0], [0.002, 0.002, 0.002], 5e-4)
    with pytest.raises(ConfigError, match="env=0 but its link 'a' is in env 1"):
        world.add_group("g", pts, MAT, link="a", kinematic=pts[:, 2] < 5e-4, env=0)
    with pytest.raises(ConfigError, match="env=-1 must be an integer"):
        world.add_collider(Sphere(radius=0.001, pose=np.eye(4)), env=-1)
    world.add_group("g", pts, MAT, link="a", kinematic=pts[:, 2] < 5e-4)
    assert world.group("g").env == 1 and world.num_envs == 2
