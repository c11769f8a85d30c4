"""Two-way coupling in ``GaussTac-Touch-v1``: the MPM reaction wrench of a pad on a free cube
is applied in SAPIEN, so a pad pushes the cube; without it the cube stays put."""
import gymnasium as gym
import numpy as np
import pytest

import gausstac_maniskill  # noqa: F401  (registers agents and tasks)
from gausstac_maniskill.errors import ConfigError

ABILITY = "floating_ability_hand_right_gausstac"
pytestmark = pytest.mark.sapien


def _make(**kw):
    return gym.make("GaussTac-Touch-v1", robot_uids=ABILITY, obs_mode="state_dict", sim_backend="physx_cpu",
                    mpm_dx=2e-3, **kw)


def _push(two_way: bool):
    """Move the floating hand's root 3 mm past first contact, at ~20 mm/s, along the index
    pad's horizontal normal; return (hand travel, cube displacement along it [m], max pad
    force [N], final cube speed [m/s], cube displacement [3])."""
    env = _make(free_cube=True, two_way=two_way, cube_gap=1e-3, sim_config=dict(sim_freq=100, control_freq=100))
    try:
        env.reset(seed=0)
        u = env.unwrapped
        n = u.pad_frame("index")[0, :3, 2].numpy().copy()
        n[2] = 0.0
        n /= np.linalg.norm(n)
        action = np.zeros(env.action_space.shape, np.float32)  # root x, y, z, rx, ry, rz; fingers; thumb
        fmax = 0.0
        for k in range(30):
            action[:3] = min((k + 1) * 2e-4, u.cube_gap + 3e-3) * n
            _, _, _, _, info = env.step(action)
            fmax = max(fmax, info["pad_force"].item())
        disp = u.cube_displacement()[0].numpy()
        travel = float(u.agent.robot.get_qpos()[0, :3].numpy() @ n)
        return travel, float(disp @ n), fmax, u.cube.linear_velocity[0].norm().item(), disp
    finally:
        env.close()


def test_pad_pushes_a_free_cube_only_with_two_way_coupling():
    travel, along, fmax, speed, disp = _push(two_way=True)
    assert fmax > 0.1
    assert along > 0.5e-3  # pushed
    assert along < travel + 1e-3 and speed < 0.05  # ... not launched (the explicit coupling is stable)
    assert abs(disp[2]) < 1e-3  # still on its pedestal

    travel, along, fmax, speed, disp = _push(two_way=False)
    assert fmax > 1.0  # the pad pressed it hard ...
    assert np.linalg.norm(disp) < 5e-5  # ... and it did not move


def test_touch_env_checks_its_arguments():
    with pytest.raises(ConfigError, match="touch_pad='palm'"):
        _make(touch_pad="palm")
    with pytest.raises(ConfigError, match="cube_half_size"):
        _make(cube_half_size=-0.01)
    with pytest.warns(UserWarning, match="lighter than"):
        _make(free_cube=True, cube_density=500.0, pad_reaction=False).close()  # 4 g at 100 Hz, explicit


def test_two_way_push_at_20_hz_control_is_not_a_launch():
    """With a two-way object the MPM steps with every SAPIEN step (100 Hz), so ManiSkill's
    default 20 Hz control pushes a steel cube instead of launching it."""
    env = _make(free_cube=True, two_way=True, cube_gap=1e-3)
    try:
        env.reset(seed=0)
        u = env.unwrapped
        assert u.mpm_every_sim_step and u.control_freq == 20
        n = u.pad_frame("index")[0, :3, 2].numpy().copy()
        n[2] = 0.0
        n /= np.linalg.norm(n)
        action = np.zeros(env.action_space.shape, np.float32)
        speeds = []
        for k in range(8):  # 1 mm per 50 ms step, to 3 mm past first contact
            action[:3] = min((k + 1) * 1e-3, u.cube_gap + 3e-3) * n
            env.step(action)
            speeds.append(u.cube.linear_velocity[0].norm().item())
        along = float(u.cube_displacement()[0].numpy() @ n)
        assert 1e-3 < along < 4e-3, along  # pushed, about as far as the hand went past contact
        # never launched: before the MPM stepped with every SAPIEN step, a 0.1 N touch launched
        # the cube at ~1 m/s. With the explicit wrench (pad_reaction=False) a stick–slip lurch
        # remained, 0.088 m/s with the cut-cell pad; the implicit springs, the default with a
        # two-way cube, carry it at 0.013 m/s. The hand moves at 0.02 m/s.
        assert u.pad_coupling == "implicit"
        assert max(speeds) < 0.05, speeds
    finally:
        env.close()
