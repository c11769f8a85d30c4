"""The PhysX helpers: poses of a batch of envs, and a wrench added to each env's rigid body as a
force at its centre of mass with the torque that keeps the moment about the entity's origin."""
from types import SimpleNamespace

import numpy as np
import sapien
import torch

from gausstac_maniskill.physx import apply_wrench, batched_pose


def test_batched_pose_is_float32_per_env():
    pose = batched_pose(np.zeros((2, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (2, 1)))
    assert pose.raw_pose.shape == (2, 7) and pose.raw_pose.dtype == torch.float32


class _Body:
    def __init__(self, origin, com_local):
        self.entity_pose = sapien.Pose(origin)
        self.cmass_local_pose = sapien.Pose(com_local)
        self.added = []

    def add_force_torque(self, force, torque):
        self.added.append((force, torque))


def test_wrench_moves_to_the_centre_of_mass_and_zero_rows_are_skipped():
    origins = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    bodies = [_Body(o, [0.0, 0.0, 0.1]) for o in origins]
    entity = SimpleNamespace(pose=SimpleNamespace(raw_pose=torch.tensor(np.c_[origins, np.tile([1, 0, 0, 0], (2, 1))])),
                             _bodies=bodies)
    w = np.zeros((2, 6))
    apply_wrench(entity, w)
    assert not bodies[0].added and not bodies[1].added
    w[0] = [1.0, 0.0, 0.0, 0.0, 0.0, 0.5]
    apply_wrench(entity, w)
    assert not bodies[1].added
    force, torque = bodies[0].added[0]
    assert force.dtype == np.float32 and torque.dtype == np.float32
    # about the centre of mass (0, 0, 0.1): the torque about the origin plus (origin - com) x force
    np.testing.assert_allclose(torque, [0.0, -0.1, 0.5], atol=1e-7)
