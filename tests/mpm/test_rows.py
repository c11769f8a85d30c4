"""Waking, sleeping and resting a group in place on the device (mpm/rows.py).

What this guards: with B envs whose pads wake and sleep at different steps, each event
changes only the group's rows on the device and the active lists, instead of copying the
whole particle state to the host and rebuilding every device array. The test drives two
envs through press, sleep while the link moves, wake, press again and rest, and checks that
this is one rebuild (the first push) and that every state field matches the host path
(forced by marking the world for a rebuild before each event) to float32 rounding.
"""
import numpy as np

from gausstac_maniskill.config import Material, SolverSettings
from gausstac_maniskill.mpm import MPMWorld, box_particles
from gausstac_maniskill.geometry.colliders import Sphere
from gausstac_maniskill.transforms import make_pose, rotation_about

MAT = Material(E=2e5, nu=0.4, density=1100.0)
DT = 0.02


def _link(env, k):
    """Env e's link at step k: moved along x and turned about z as the steps go."""
    return make_pose([0.001 * k + 0.0005 * env, 0.0, 0.0], rotation_about([0, 0, 1], 0.05 * k + 0.1 * env))


def _events(world, k):
    """Env 0 sleeps at step 3 and wakes at 6; env 1 sleeps at 4 (after a rest) and wakes at 7."""
    if k == 3:
        world.set_awake("pad0", False)
    if k == 4:
        world.rest_group("pad1")
        world.set_awake("pad1", False)
    if k == 6:
        world.set_awake("pad0", True)
    if k == 7:
        world.set_awake("pad1", True)


def _run(rebuild_at_events: bool):
    world = MPMWorld(SolverSettings(dx=1e-3, gravity=(0.0, 0.0, -9.81), mass_scaling=100.0))
    h = world.settings.particle_spacing
    pts = box_particles([-0.004, -0.004, -0.004], [0.004, 0.004, 0.0], h)
    cols = []
    for e in range(2):
        T = _link(e, 0)
        world.add_link(f"base{e}", T, env=e)
        world.add_group(f"pad{e}", pts @ T[:3, :3].T + T[:3, 3], MAT, link=f"base{e}", kinematic=pts[:, 2] < -0.003,
                        env=e)
        cols.append(world.add_collider(Sphere(radius=0.003, pose=make_pose(T[:3, 3] + [0, 0, 0.0034]), friction=0.5),
                                       env=e))
    for k in range(9):
        if rebuild_at_events:
            world._pull()
            world._dirty = True  # the host path: pull everything, change it there, rebuild
        _events(world, k)
        for e in range(2):
            T = _link(e, k + 1)
            world.set_link_pose(f"base{e}", T)
            world.set_collider_pose(cols[e], make_pose(T[:3, 3] + [0, 0, 0.0034 - 4e-4 * min(k + 1, 3)]))
        world.step(DT)
    return world


def test_wake_and_sleep_in_place_match_the_host_path():
    light, full = _run(False), _run(True)
    assert light.rebuilds == 1 and full.rebuilds > 5
    assert light.group("pad0").awake and light.group("pad1").awake
    # measured: positions 7e-9 m, velocities 5e-7 m/s (of 0.06), F 4.5e-6, stress 0.8 Pa (of 92 kPa)
    for read, atol in (("positions", 1e-7), ("velocities", 5e-6), ("deformation_gradients", 5e-5)):
        a, b = getattr(light, read)(), getattr(full, read)()
        assert np.isfinite(a).all()
        np.testing.assert_allclose(a, b, rtol=0, atol=atol, err_msg=read)
    np.testing.assert_allclose(light.stresses(), full.stresses(), rtol=0, atol=1e-3 * np.abs(full.stresses()).max())
    # the presses after waking are real contacts
    assert np.linalg.norm(light.collider_wrench(0)[0]) > 1e-3 and np.linalg.norm(light.collider_wrench(1)[0]) > 1e-3
