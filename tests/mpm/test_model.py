"""The MPM world's description is immutable: adding a link, group, collider or wall gives a new
:class:`Model` and leaves the earlier one as it was; its arrays cannot be written; what changes
while the world steps (positions, awake flags, poses) is not in it (no Taichi launch)."""
import dataclasses

import numpy as np
import pytest

from gausstac_maniskill.config import Material, SolverSettings
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.geometry import Box, Sphere, box_particles
from gausstac_maniskill.mpm import Model
from gausstac_maniskill.mpm.model import REST_FIELDS
from gausstac_maniskill.mpm.solver import MPMWorld
from gausstac_maniskill.transforms import make_pose


@pytest.fixture
def world():
    w = MPMWorld(SolverSettings(dx=2e-3))
    w.add_link("tip", make_pose([0.0, 0.0, 0.01]))
    pts = box_particles([0, 0, 0], [0.006, 0.006, 0.004], 1e-3)
    w.add_group("pad", pts, Material(), link="tip", kinematic=pts[:, 2] < 0.001)
    return w


def test_adding_a_part_gives_a_new_model_and_keeps_the_old(world):
    before = world.model
    rows = before.num_particles
    world.add_group("ball", box_particles([-0.002, -0.002, 0.02], [0.002, 0.002, 0.024], 1e-3), Material(E=1e5), field=1, env=1)
    after = world.model
    assert after is not before
    assert before.num_particles == rows and [g.name for g in before.groups] == ["pad"]
    assert [g.name for g in after.groups] == ["pad", "ball"] and after.groups[1].start == rows
    assert before.num_envs == 1 and after.num_envs == 2
    assert len(before.materials) == 1 and len(after.materials) == 2
    world.add_collider(Sphere(radius=0.003, pose=make_pose([0, 0, 0.03])))
    world.add_slip_wall(2, 0.0)
    assert len(after.colliders) == 0 and len(world.model.colliders) == 1 and len(world.model.walls) == 1
    assert world.groups[1].model is world.model.groups[1]


def test_the_model_cannot_be_changed_in_place(world):
    m = world.model
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.num_envs = 3
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.groups[0].count = 1
    for key in REST_FIELDS:
        with pytest.raises(ValueError, match="read-only"):
            getattr(m.particles, key)[:1] = 0
    with pytest.raises(ValueError, match="read-only"):
        m.group_bind[0] = 0
    with pytest.raises(TypeError):
        m._link_at["other"] = 1
    # the world's host rows of the rest fields are the model's arrays, not copies that could drift
    assert world._host_parts.X0 is m.particles.X0 and world._host_parts.kind is m.particles.kind


def test_state_lives_outside_the_model(world):
    m = world.model
    world.set_awake("pad", False)
    world.set_link_pose("tip", make_pose([0.0, 0.0, 0.02]))
    assert world.model is m  # sleeping and moving change the state, not the description
    assert not world.group("pad").awake and world.group("pad").start == m.groups[0].start
    with pytest.raises(AttributeError, match="model"):
        world.group("pad").start = 5  # a group's description reads through and stays fixed


def test_a_failed_add_leaves_the_model_unchanged(world):
    m = world.model
    with pytest.raises(ConfigError, match="already exists"):
        world.add_group("pad", np.zeros((1, 3)), Material())
    with pytest.raises(ConfigError, match="env"):
        world.add_group("late", np.zeros((1, 3)), Material(), link="tip", env=3)
    with pytest.raises(ConfigError, match="already registered"):
        world.add_link("tip", np.eye(4))
    assert world.model is m and m.num_envs == 1


def test_collider_shape_is_fixed_when_added():
    w = MPMWorld(SolverSettings(dx=2e-3))
    box = Box(half_extents=(0.01, 0.02, 0.03), friction=0.7, pose=make_pose([0, 0, 0.05]))
    w.add_collider(box, env=2)
    c = w.model.colliders[0]
    assert c.kind == box.kind and c.params == tuple(np.asarray(box.params(), np.float32).tolist())
    assert c.friction == pytest.approx(0.7) and c.env == 2 and c.sdf_shape is None and w.num_envs == 3
    assert c.bound == pytest.approx(np.linalg.norm([0.01, 0.02, 0.03]))


def test_a_model_checks_its_contact_mode():
    with pytest.raises(ConfigError, match="contact"):
        Model(SolverSettings(), "nodes")
