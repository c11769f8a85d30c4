"""Pad reaction on the links (``pad_reaction=True``, issue 11 point 2): a finger pressed
into a fixed cube yields to its pad's push; without the reaction it is held where its drive
puts it."""
import gymnasium as gym
import numpy as np
import pytest
import torch

import gausstac_maniskill  # noqa: F401  (registers agents and tasks)
from gausstac_maniskill.tasks.base import PAD_REACTION_MIN_FREQ

pytestmark = pytest.mark.sapien


def _press(reaction: bool, steps: int = 6):
    """The Allegro index finger closes on a fixed cube 1 mm in front of its pad: its three
    flexion joints' targets move 0.01 rad per control step. Returns (index pad force per
    step [N], lag of those joints behind their drive targets at the end [rad], env)."""
    env = gym.make("GaussTac-Touch-v1", obs_mode="state_dict", sim_backend="physx_cpu", mpm_dx=2e-3,
                   cube_gap=1e-3, pad_reaction=reaction, sim_config=dict(sim_freq=PAD_REACTION_MIN_FREQ))
    env.reset(seed=0)
    u = env.unwrapped
    action = np.zeros(env.action_space.shape, np.float32)
    names = u.agent.controller.config.joint_names
    flex = [names.index(f"joint_{j}.0") for j in (1, 2, 3)]
    action[flex] = 0.1  # of the controller's +-0.1 rad
    forces = []
    for _ in range(steps):
        env.step(action)
        forces.append(u.pad_force("index").item())
    robot = u.agent.robot
    qidx = [u.action_joint_index[i] for i in flex]
    lag = (robot.get_drive_targets()[0, qidx] - robot.get_qpos()[0, qidx]).numpy()
    return forces, lag, env


def test_finger_closing_on_a_cube_is_stopped_by_its_pad_only_with_the_reaction():
    forces, lag, env = _press(reaction=True)
    try:
        u = env.unwrapped
        assert u.mpm_every_sim_step
        # the last MPM step's reaction on the index link is the cube's, reversed
        i = u.pad_links.index(u.pad_geometry("index").spec.link)
        F_link = u.pad_link_wrench()[0, i, :3].numpy()
        F_cube = u.object_wrench("cube")[0, :3].numpy()
        assert np.linalg.norm(F_cube) > 1.0
        np.testing.assert_allclose(F_link, -F_cube, atol=1e-3 * np.linalg.norm(F_cube))
        # what acts during the next SAPIEN step is part of the env state, for exact replay
        state = u.get_state_dict()
        w = state["task"]["link_wrench"].clone()
        assert w.shape == (1, 6 * len(u.pad_links)) and torch.count_nonzero(w) > 0
        u._link_wrench[:] = 0.0
        u.set_state_dict(state)
        # (to float32, what SAPIEN is given: ManiSkill's set_state_dict passes leaves as float32)
        np.testing.assert_array_equal(u._link_wrench.reshape(1, -1).astype(np.float32), w.numpy().astype(np.float32))
    finally:
        env.close()
    assert all(np.isfinite(forces)) and min(forces) >= 0.0
    # the drives push on (their targets stay ahead of the joints), the pad pushes back:
    # the press settles where they balance (measured 11.08 N at 2 mm)
    assert np.all(lag > 0.0)
    assert forces[-1] > 1.0 and abs(forces[-1] - forces[-2]) < 0.02 * forces[-1]

    forces_off, _, env = _press(reaction=False)
    env.close()
    # kinematic fingers crush the pad against its rigid core instead (measured 46-57 N)
    assert min(forces_off[2:]) > 3 * forces[-1]


def test_pad_reaction_below_its_stable_rate_warns():
    with pytest.warns(UserWarning, match="pad_reaction=True at sim_freq=100 Hz"):
        gym.make("GaussTac-Touch-v1", obs_mode="state_dict", sim_backend="physx_cpu", mpm_dx=2e-3,
                 pad_reaction=True).close()
