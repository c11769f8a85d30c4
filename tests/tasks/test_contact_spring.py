"""ObjectSpring on its own: a free box pushed by pads on kinematic anchors, one PGS step, no
gravity, against the implicit Euler step of the springs it claims to be.

A spring of stiffness K preloaded by the gap δ = |F|/K moves a free body of mass m by
δ r/(1+r), r = K dt²/m, in one implicit step: a heavy body (r << 1) takes the full force
(f dt²/m), a light one (r >> 1) only closes the gap. Two opposed pads (a pinch) move it to
(F1 - F2) / (m/dt² + K1 + K2) toward the weaker one: what PhysX's PGS missed with one soft
constraint per pad (``bench hold``: +4.08 µm where this is -49.60 µm), the reason for one
spring per object.
"""
import numpy as np
import pytest
import sapien

from gausstac_maniskill.tasks.contact_spring import OBJECT_GAIN, ObjectSpring

DT = 0.01
CENTRE = np.array([0.0, 0.0, 0.5])


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
    body.set_pose(sapien.Pose(CENTRE))
    return body


def _pad(scene, at):
    """A kinematic "pad link" at ``at`` (5 cm off: no collision)."""
    a = scene.create_actor_builder()
    a.add_box_collision(half_size=[0.005] * 3)
    anchor = a.build_kinematic(name="pad")
    anchor.set_pose(sapien.Pose(at))
    return anchor.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)


def _row(link, force, point, depth):
    """The link's contact row for a pad pushing the object with ``force`` [N] at ``point``."""
    origin = np.asarray(link.entity_pose.p, np.float64)
    on_link = -np.asarray(force, np.float64)
    return np.concatenate([on_link, np.cross(point - origin, on_link), [depth]])


def _step(scene, body):
    p0 = np.asarray(body.pose.p, np.float64).copy()
    scene.step()
    return np.asarray(body.pose.p, np.float64) - p0


@pytest.mark.parametrize("mass", [0.01, 10.0])
@pytest.mark.parametrize("n", [(0.0, -1.0, 0.0), (0.034, -0.992, -0.12)])
def test_one_pad_moves_the_box_as_an_implicit_preloaded_spring(pgs_scene, mass, n):
    body = _box(pgs_scene, mass)
    link = _pad(pgs_scene, CENTRE + [0.0, 0.05, 0.0])
    spring = ObjectSpring(pgs_scene, body)
    n = np.asarray(n) / np.linalg.norm(n)
    f, depth = 1.9, 0.57e-3  # N, m: the index pad on the held 10 g cube
    point = CENTRE - 0.01 * n  # on the face, the line of action through the centre
    w = spring.take([(_row(link, f * n, point, depth), link)], friction=0.0)
    assert np.allclose(w[:3], f * n) and np.allclose(w[3:], 0.0, atol=1e-9)
    dp = _step(pgs_scene, body)
    K = OBJECT_GAIN * f / depth
    r = K * DT ** 2 / mass
    expected = f / K * r / (1 + r)
    assert dp @ n == pytest.approx(expected, rel=0.02)
    assert np.linalg.norm(dp - (dp @ n) * n) < 0.02 * abs(expected) + 1e-9  # along the force only


def test_an_off_centre_push_turns_a_heavy_box_by_its_moment(pgs_scene):
    """The preloaded twist and swing drives apply the pads' moment about the centre of mass:
    a 100 kg box (the springs' response within the step is under 6 % of its inertia's) pushed
    off its centre spins up as the moment alone would, about all three axes."""
    mass = 100.0
    body = _box(pgs_scene, mass)
    link = _pad(pgs_scene, CENTRE + [0.0, 0.05, 0.0])
    n = np.array([0.0, -1.0, 0.0])
    point = CENTRE + [0.004, 0.01, 0.003]  # on the +y face, off its centre
    w = ObjectSpring(pgs_scene, body).take([(_row(link, 1.9 * n, point, 0.57e-3), link)], friction=0.0)
    moment = np.cross(point - CENTRE, 1.9 * n)  # about x and z
    assert np.allclose(w[3:], moment, atol=1e-9)
    pgs_scene.step()
    inertia = mass * 0.02 ** 2 / 6  # a cube's, about any axis through its centre
    spin = np.asarray(body.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent).angular_velocity)
    assert np.allclose(spin, moment / inertia * DT, rtol=0.06, atol=0.01 * np.abs(moment).max() / inertia * DT), spin


@pytest.mark.parametrize("friction", [0.0, 1.0])
def test_two_opposed_pads_move_the_box_to_their_implicit_balance(pgs_scene, friction):
    body = _box(pgs_scene, 0.01)
    thumb, index = _pad(pgs_scene, CENTRE - [0.0, 0.05, 0.0]), _pad(pgs_scene, CENTRE + [0.0, 0.05, 0.0])
    y = np.array([0.0, 1.0, 0.0])
    pads = [(thumb, 0.115, 0.10e-3, y), (index, 1.897, 0.57e-3, -y)]  # the held 10 g cube (bench hold)
    rows = [(_row(link, f * n, CENTRE - 0.01 * n, depth), link) for link, f, depth, n in pads]
    spring = ObjectSpring(pgs_scene, body)
    w = spring.take(rows, friction)
    assert np.allclose(w[:3], (0.115 - 1.897) * y)
    dp = _step(pgs_scene, body)
    K = sum(OBJECT_GAIN * f / depth for _, f, depth, _ in pads)
    expected = (0.115 - 1.897) / (0.01 / DT ** 2 + K)  # -49.6 µm
    assert dp[1] == pytest.approx(expected, rel=0.02)
    assert abs(dp[0]) + abs(dp[2]) < 0.02 * abs(expected)


def test_follows_the_pads_within_the_step(pgs_scene):
    """The target moves with the pads: a box pinched at balance by two pads moving up at
    1 cm/s moves up with them in the step (a spring fixed in the world would hold it back)."""
    body = _box(pgs_scene, 0.05)
    y = np.array([0.0, 1.0, 0.0])
    pads = {side: _pad(pgs_scene, CENTRE - side * 0.05 * y) for side in (1.0, -1.0)}
    for side, link in pads.items():
        link.kinematic_target = sapien.Pose(CENTRE - side * 0.05 * y + [0.0, 0.0, 1e-4])
    pgs_scene.step()  # the pads now move at 1 cm/s (their velocity as the spring reads it)
    assert np.allclose([link.linear_velocity[2] for link in pads.values()], 0.01, rtol=1e-3)
    body.set_pose(sapien.Pose(CENTRE))
    spring = ObjectSpring(pgs_scene, body)
    spring.take([(_row(link, 1.0 * side * y, CENTRE - 0.01 * side * y, 0.3e-3), link) for side, link in pads.items()],
                friction=1.0)
    dp = _step(pgs_scene, body)
    assert dp[2] == pytest.approx(1e-4, rel=0.05), dp
    assert abs(dp[1]) < 1e-6


def test_never_pulls_and_release_frees(pgs_scene):
    body = _box(pgs_scene, 0.01)
    link = _pad(pgs_scene, CENTRE + [0.0, 0.05, 0.0])
    spring = ObjectSpring(pgs_scene, body)
    n = np.array([0.0, -1.0, 0.0])
    spring.take([(_row(link, 1.0 * n, CENTRE + [0.0, 0.01, 0.0], 1e-3), link)], friction=0.0)
    body.set_pose(sapien.Pose(CENTRE + [0.0, -1e-3, 0.0]))  # already 1 mm past where the spring lets go
    pgs_scene.step()
    assert np.asarray(body.pose.p)[1] == pytest.approx(-1e-3, abs=1e-9)
    spring.release()
    body.set_pose(sapien.Pose(CENTRE))
    pgs_scene.step()
    assert np.allclose(np.asarray(body.pose.p), CENTRE, atol=1e-9)
    assert np.array_equal(spring.take([(np.zeros(7), link)], 0.5), np.zeros(6)) and not spring.active
