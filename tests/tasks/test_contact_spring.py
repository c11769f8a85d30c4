"""ContactSpring on its own: a free box pushed by one spring riding on a kinematic anchor,
one PGS step, no gravity, against the implicit spring it claims to be.

A spring of stiffness K preloaded by the gap δ = |F|/K moves a free body of mass m by
δ r/(1+r), r = K dt²/m, in one implicit step: a heavy body (r << 1) takes the full force
(f dt²/m), a light one (r >> 1) only closes the gap. These check the spring's one-sided
limit against that formula (on the hand, ``bench hold`` finds each limit within 2 µm of it).
They do not check the friction drives, which pin GaussTac-GraspLiftCube's held light cube
against the pads' unequal forces (BENCHMARKS.md, issue 11 seventh step).
"""
import numpy as np
import pytest
import sapien

from gausstac_maniskill.tasks.contact_spring import OBJECT_GAIN, ContactSpring

DT = 0.01


@pytest.fixture
def pgs_scene():
    saved = sapien.physx.get_scene_config()
    config = sapien.physx.PhysxSceneConfig()
    config.gravity = np.zeros(3)
    config.enable_tgs = False
    sapien.physx.set_scene_config(config)
    try:
        scene = sapien.Scene()
        scene.set_timestep(DT)
        yield scene
    finally:
        sapien.physx.set_scene_config(saved)


def _box(scene, mass: float):
    b = scene.create_actor_builder()
    b.add_box_collision(half_size=[0.01] * 3, density=mass / 8e-6)
    body = b.build(name="body")
    body.set_pose(sapien.Pose([0.0, 0.0, 0.5]))
    a = scene.create_actor_builder()
    a.add_box_collision(half_size=[0.005] * 3)
    anchor = a.build_kinematic(name="anchor")
    anchor.set_pose(sapien.Pose([0.0, 0.05, 0.5]))  # the "pad link", 5 cm off: no collision
    return body, anchor


@pytest.mark.parametrize("mass", [0.01, 10.0])
@pytest.mark.parametrize("n", [(0.0, -1.0, 0.0), (0.034, -0.992, -0.12)])
def test_one_step_matches_an_implicit_preloaded_spring(pgs_scene, mass, n):
    body, anchor = _box(pgs_scene, mass)
    spring = ContactSpring(pgs_scene, body, anchor)
    n = np.asarray(n) / np.linalg.norm(n)
    f, depth = 1.9, 0.57e-3  # N, m: the index pad on the held 10 g cube
    point = np.array([0.0, 0.0, 0.5]) - 0.01 * n  # on the face, the line of action through the centre
    assert spring.update(f * n, point, depth)
    p0 = np.asarray(body.pose.p, np.float64).copy()
    pgs_scene.step()
    dp = np.asarray(body.pose.p, np.float64) - p0
    K = OBJECT_GAIN * f / depth
    r = K * DT ** 2 / mass
    expected = f / K * r / (1 + r)
    assert dp @ n == pytest.approx(expected, rel=0.02)
    assert np.linalg.norm(dp - (dp @ n) * n) < 0.02 * abs(expected) + 1e-9  # along the force only


def test_never_pulls_and_release_frees(pgs_scene):
    body, anchor = _box(pgs_scene, 0.01)
    spring = ContactSpring(pgs_scene, body, anchor)
    n = np.array([0.0, -1.0, 0.0])
    spring.update(1.0 * n, np.array([0.0, 0.02, 0.5]), 1e-3)
    body.set_pose(sapien.Pose([0.0, -1e-3, 0.5]))  # already 1 mm past where the spring lets go
    pgs_scene.step()
    assert np.asarray(body.pose.p)[1] == pytest.approx(-1e-3, abs=1e-9)
    spring.release()
    body.set_pose(sapien.Pose([0.0, 0.0, 0.5]))
    pgs_scene.step()
    assert np.allclose(np.asarray(body.pose.p), [0.0, 0.0, 0.5], atol=1e-9)
    assert np.array_equal(spring.take(np.zeros(7), 0.5), np.zeros(6)) and not spring.active
