"""Optical sensors on a task's pads (``optical=`` of the GaussTac tasks): the observation's
images and markers, that they are the sensor's rendering of the same maps, that they are copies,
that an env without them has none, and the arguments' errors. Recording and replay by env states
are covered by tests/test_collect.py (its recording carries an optical index pad)."""
import gymnasium as gym
import numpy as np
import pytest
import torch

import gausstac_maniskill  # noqa: F401  (registers the tasks)
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.optical import pad_images, pad_preset

TASK = "GaussTac-PressCube-v1"


@pytest.fixture(scope="module")
def env(sapien_vulkan):
    e = gym.make(TASK, obs_mode="state_dict", mpm_dx=2e-3, optical={"index": "gelsight_mini", "thumb": "gelsight"},
                 optical_width=64)
    yield e
    e.close()


def test_optical_pads_give_images_of_their_maps(env):
    from gausstac_maniskill.experts import make_expert

    obs, _ = env.reset(seed=0)
    expert = make_expert(env)
    expert.reset()
    for _ in range(6):
        obs, *_ = env.step(expert.act(obs))
    index = obs["tactile"]["index"]
    assert index["rgb"].shape == (1, 64, 64, 3) and index["rgb"].dtype == torch.uint8
    assert index["markers"].ndim == 3 and index["markers"].shape[-1] == 2
    assert "rgb" not in obs["tactile"]["middle"]
    assert float(index["force"].sum()) > 0.1  # pressing: the image shows a touch
    spec = next(p for p in env.unwrapped.agent.gausstac_pads if p.name == "index")
    sensor = pad_preset("gelsight_mini", spec.layout, 64)
    rgb, markers = pad_images(index["depth"], index["shear"], sensor)
    assert torch.equal(rgb, index["rgb"]) and torch.equal(markers, index["markers"])
    rest, _ = pad_images(torch.zeros_like(index["depth"]), torch.zeros_like(index["shear"]), sensor)
    assert (rgb.int() - rest.int()).abs().max() > 10  # the touch changes the image
    index["rgb"].zero_()  # a copy: the next observation is untouched
    again = env.unwrapped.get_obs(unflattened=True)["tactile"]["index"]["rgb"]
    assert torch.equal(again, rgb)


def test_bad_optical_arguments_are_named(sapien_vulkan):
    """(The constructor's bad values are in tests/tasks/test_conventions.py's BAD.)"""
    with pytest.raises(ConfigError, match="pinky"):
        gym.make(TASK, optical={"pinky": "gelsight"}, mpm_dx=2e-3).reset(seed=0)


def test_an_agent_can_carry_optical_pads(sapien_vulkan):
    """add_gausstac_pads(optical=...) puts the sensor on the agent: every task it runs in shows
    the images without being told."""
    from gausstac_maniskill.agents import add_gausstac_pads
    from gausstac_maniskill.agents.ability import ABILITY_FINGER_HULL, ABILITY_PAD_AXES

    cls = add_gausstac_pads("floating_ability_hand_right", {"index": "index_L2"}, uid="ability_optical_index_test",
                            axes={"index_L2": ABILITY_PAD_AXES["index_L2"]}, mesh=ABILITY_FINGER_HULL, thickness=2e-3,
                            optical="gelsight_mini")
    assert cls.gausstac_optical == {None: "gelsight_mini"}
    env = gym.make("GaussTac-Touch-v1", robot_uids=cls.uid, obs_mode="state_dict", mpm_dx=2e-3, optical_width=32)
    try:
        obs, _ = env.reset(seed=0)
        assert obs["tactile"]["index"]["rgb"].shape == (1, 32, 32, 3)
    finally:
        env.close()
    with pytest.raises(ConfigError, match="optical"):
        add_gausstac_pads("floating_ability_hand_right", ["index_L2"], uid="ability_optical_bad", optical=3,
                          register=False)
