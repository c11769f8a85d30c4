"""make_tactile: ManiSkill's own dexterous tasks (Allegro, DClaw, TriFinger) with GaussTac pads keep
their scene, reward and success, and gain tactile maps that are finite, non-negative and light up
when a fingertip presses the object. Runs on a 2 mm grid (the pads' shape and the coupling are
the same; only the resolution is coarser)."""
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch

import gausstac_maniskill as gm
from gausstac_maniskill.errors import ConfigError, ResolutionWarning

FAMILIES = {"RotateSingleObjectInHandLevel0-v1": ("thumb", "index", "middle", "ring"),
            "RotateValveLevel0-v1": ("f1", "f2", "f3"),
            "TriFingerRotateCubeLevel0-v1": ("f0", "f120", "f240")}
KW = dict(obs_mode="state_dict", mpm_dx=2e-3)


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ResolutionWarning)  # a 2 mm grid under-resolves the 4 mm layer (known)
        yield


def _stock(env_id):
    import mani_skill.envs  # noqa: F401  (registers ManiSkill's tasks)

    return gym.make(env_id, obs_mode="state_dict")


@pytest.mark.parametrize("env_id", FAMILIES)
def test_random_actions_keep_the_task_and_give_finite_non_negative_maps(env_id):
    env = gm.make_tactile(env_id, **KW)
    stock = _stock(env_id)
    try:
        obs, info = env.reset(seed=0)
        stock_obs, _ = stock.reset(seed=0)
        assert set(obs["tactile"]) == set(FAMILIES[env_id])
        assert set(obs["agent"]) == set(stock_obs["agent"]) and set(obs["extra"]) == set(stock_obs["extra"])
        assert env.spec.max_episode_steps == stock.spec.max_episode_steps
        env.action_space.seed(0)
        for _ in range(20):
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            assert torch.isfinite(reward).all() and "success" in info
            for pad, maps in obs["tactile"].items():
                for key, m in maps.items():
                    assert torch.isfinite(m).all(), (pad, key)
                assert (maps["force"] >= 0).all(), pad
    finally:
        env.close()
        stock.close()


def test_closing_the_allegro_hand_on_the_cube_lights_the_thumbs_map():
    env = gm.make_tactile("RotateSingleObjectInHandLevel0-v1", **KW)
    try:
        env.reset(seed=0)
        peak = {}
        for _ in range(12):  # every joint towards its upper limit: the fingers curl round the cube
            obs, *_ = env.step(env.action_space.high)
            for pad, maps in obs["tactile"].items():
                peak[pad] = max(peak.get(pad, 0.0), float(maps["force"].sum()))
        assert peak["thumb"] > 0.05, peak
        assert env.unwrapped.pad_solver_used == "fem"
    finally:
        env.close()


@pytest.mark.parametrize("env_id", ["RotateValveLevel0-v1", "TriFingerRotateCubeLevel0-v1"])
def test_with_the_pads_far_from_everything_reward_and_success_are_the_stock_tasks(env_id):
    rewards, success = [], []
    for make in (lambda: _stock(env_id), lambda: gm.make_tactile(env_id, **KW)):
        env = make()
        try:
            env.reset(seed=3)
            a = np.zeros(env.action_space.shape, np.float32)
            out = [env.step(a) for _ in range(4)]
            rewards.append([float(o[1]) for o in out])
            success.append([bool(o[4]["success"]) for o in out])
            if hasattr(env.unwrapped, "tactile"):
                assert all(float(m["force"].sum()) == 0.0 for m in out[-1][0]["tactile"].values())
        finally:
            env.close()
    assert rewards[0] == rewards[1] and success[0] == success[1]


def test_a_task_without_a_hand_with_pads_is_a_named_error():
    with pytest.raises(ConfigError, match=r"has no GaussTac pads; hands with pads: .*allegro_hand_right_touch.*dclaw"):
        gm.make_tactile("PushCube-v1", **KW)
    with pytest.raises(ConfigError, match="no registered ManiSkill task 'RotateValveLevel9-v1'"):
        gm.make_tactile("RotateValveLevel9-v1")


def test_a_gausstac_task_is_made_as_it_is():
    env = gm.make_tactile("GaussTac-Gesture-v1", obs_mode="state_dict", mpm_dx=2e-3)
    try:
        assert type(env.unwrapped).__name__ == "GestureEnv" or "Gesture" in type(env.unwrapped).__name__
    finally:
        env.close()


@pytest.mark.parametrize("level", [2, 3])
def test_ycb_levels_work_where_their_assets_are(level):
    from mani_skill import ASSET_DIR

    if not (ASSET_DIR / "assets/mani_skill2_ycb/info_pick_v0.json").is_file():
        pytest.skip(f"ManiSkill's YCB objects are not downloaded here ({ASSET_DIR}/assets/mani_skill2_ycb): "
                    "python -m mani_skill.utils.download_asset ycb")
    env = gm.make_tactile(f"RotateSingleObjectInHandLevel{level}-v1", **KW)
    try:
        obs, _ = env.reset(seed=0)
        obs, *_ = env.step(env.action_space.sample())
        assert all(torch.isfinite(m["force"]).all() for m in obs["tactile"].values())
    finally:
        env.close()
