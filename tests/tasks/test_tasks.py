"""The four GaussTac tasks: gym.make/reset/step on physx_cpu, obs layout, experts, bad input."""
import gymnasium as gym
import numpy as np
import pytest
import torch

import gausstac_maniskill  # noqa: F401  (registers the tasks)
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.experts import make_expert

TASKS = ["GaussTac-Gesture-v1", "GaussTac-PressCube-v1", "GaussTac-SlideCube-v1", "GaussTac-SqueezeSponge-v1"]
PADS = ["thumb", "index", "middle", "ring"]
pytestmark = pytest.mark.sapien


def _make(env_id, **kw):
    kw.setdefault("obs_mode", "state_dict")
    return gym.make(env_id, sim_backend="physx_cpu", **kw)


@pytest.mark.parametrize("env_id", TASKS)
def test_make_reset_step_and_obs_layout(env_id):
    env = _make(env_id)
    try:
        obs, info = env.reset(seed=0)
        assert "success" in info
        for _ in range(3):
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample() * 0.1)
        assert reward.shape == (1,) and torch.isfinite(reward).all()
        assert sorted(obs["tactile"]) == sorted(PADS)
        for pad in PADS:
            m = obs["tactile"][pad]
            assert set(m) == {"depth", "shear", "force"}
            assert m["depth"].shape == (1, 16, 16) and m["depth"].dtype == torch.float32
            assert m["shear"].shape == (1, 16, 16, 2) and m["shear"].dtype == torch.float32
            assert m["force"].shape == (1, 16, 16) and m["force"].dtype == torch.float32
        # the observation space describes the tactile entries too
        space = env.unwrapped.single_observation_space
        assert space["tactile"]["index"]["shear"].shape == (16, 16, 2)
        timing = env.unwrapped.step_timing
        assert {"physics", "mpm", "tactile", "render", "reset"} <= set(timing)
    finally:
        env.close()


@pytest.mark.parametrize("env_id", TASKS)
def test_scripted_expert_succeeds_on_fixed_seed(env_id):
    env = _make(env_id, control_mode="pd_joint_delta_pos")
    try:
        obs, _ = env.reset(seed=1)
        expert = make_expert(env)
        expert.reset()
        success = False
        for _ in range(60):
            obs, reward, terminated, truncated, info = env.step(expert.act(obs))
            if info["success"].all():
                success = True
                break
            assert not info.get("fail", torch.zeros(1, dtype=torch.bool)).any(), info
        assert success, info
        if env_id != "GaussTac-Gesture-v1":  # contact tasks: the index pad is deformed
            assert obs["tactile"]["index"]["depth"].max() > 1e-4
    finally:
        env.close()


def test_state_obs_mode_flattens_tactile_into_the_vector():
    env = _make("GaussTac-Gesture-v1", obs_mode="state")
    try:
        obs, _ = env.reset(seed=0)
        assert obs.ndim == 2 and obs.shape[0] == 1
        # 4 pads x (256 depth + 512 shear + 256 force) tactile values are part of it
        assert obs.shape[1] > 4 * 1024
    finally:
        env.close()


def _press_to_target(env, steps: int):
    """PressCube's expert from seed 3 until success (at most ``steps``), the reported force the
    index map's sum at every step; then the force within 15 % of the target, on the index pad
    alone. Returns (obs, expert)."""
    obs, _ = env.reset(seed=3)
    expert = make_expert(env)
    expert.reset()
    for _ in range(steps):
        obs, _, _, _, info = env.step(expert.act(obs))
        assert torch.allclose(info["force"], obs["tactile"]["index"]["force"].sum(dim=(1, 2)), rtol=1e-5)
        if info["success"].all():
            break
    assert info["success"].all(), info
    target = env.unwrapped.target_force
    assert (info["force"] - target).abs().item() < 0.15 * target.item()
    for pad in ("thumb", "middle", "ring"):  # only the index pad touches the cube
        assert obs["tactile"][pad]["force"].abs().sum() == 0
    return obs, expert


def test_press_force_is_the_tactile_force_sum_and_tracks_the_target():
    env = _make("GaussTac-PressCube-v1")
    try:
        _press_to_target(env, 30)
    finally:
        env.close()


def test_press_cube_with_pads_at_equilibrium():
    """pad_solver="fem" in a task: the expert presses the cube to its target force with the
    index pad solved at equilibrium (2 mm grid: 1 mm elements, for speed); the recorded state
    carries the pad's solution and restores it."""
    with pytest.warns(Warning, match="spans only"):
        env = _make("GaussTac-PressCube-v1", pad_solver="fem", mpm_dx=2e-3)
        try:
            obs, expert = _press_to_target(env, 40)
            state = env.unwrapped.get_state_dict()
            assert bool(state["gausstac"]["fem1_solved"].all())  # the index pad (pads: thumb, index, ...)
            action = expert.act(obs)
            a = env.step(action)[0]["tactile"]["index"]["force"]
            env.unwrapped.set_state_dict(state)
            b = env.step(action)[0]["tactile"]["index"]["force"]
            assert torch.equal(a, b)
            # random actions (seed 4 reaches a warm start of the friction solve with no point loaded)
            env.reset(seed=4)
            env.action_space.seed(4)
            for _ in range(60):
                obs = env.step(env.action_space.sample())[0]
                assert all(torch.isfinite(v).all() for m in obs["tactile"].values() for v in m.values())
        finally:
            env.close()
    with pytest.raises(ConfigError, match="pad_solver"):
        _make("GaussTac-PressCube-v1", pad_solver="implicit")


def test_finite_strain_pads_meet_the_sponge_as_mpm_pads():
    """pad_solver="auto" with fem_model="neo_hookean" in a task with a soft object: the pads
    become MPM pads (GaussTacSim.add_soft_object decides, and pad_solver_used reports what it
    decided); pad_solver="fem" with it is refused, naming both ways out. Guards the wiring, not
    physics."""
    with pytest.warns(Warning, match="spans only"):
        env = _make("GaussTac-SqueezeSponge-v1", mpm_dx=2e-3, fem_model="neo_hookean")
        try:
            env.reset(seed=0)
            assert env.unwrapped.pad_solver_used == "mpm"
            assert all(sim.pad_solver == "mpm" for sim in env.unwrapped.cosims)
        finally:
            env.close()
        # refused while gym.make builds the env's scene (add_soft_object): no env is left to close
        with pytest.raises(ConfigError, match="fem_model='linear' or pad_solver='mpm'"):
            _make("GaussTac-SqueezeSponge-v1", mpm_dx=2e-3, pad_solver="fem", fem_model="neo_hookean")


def test_squeeze_sponge_with_pads_at_equilibrium():
    """The default pads (pad_solver="auto") with a soft object are solved at equilibrium:
    SqueezeSponge's expert squeezes the MPM sponge to its target compression against the index
    pad (2 mm grid), whose force map reads the push and agrees with the task's stress-read force
    (pressure map × taxel area) within 5 %."""
    with pytest.warns(Warning, match="spans only"):
        env = _make("GaussTac-SqueezeSponge-v1", mpm_dx=2e-3, control_mode="pd_joint_delta_pos")
        try:
            obs, _ = env.reset(seed=1)
            assert env.unwrapped.pad_solver_used == "fem"
            expert = make_expert(env)
            expert.reset()
            for _ in range(30):
                obs, _, _, _, info = env.step(expert.act(obs))
                if info["success"].all():
                    break
            assert info["success"].all(), info
            force = obs["tactile"]["index"]["force"].sum()
            assert force > 0.5 and info["pad_force"].item() == pytest.approx(force.item(), rel=0.05)
        finally:
            env.close()


def test_invalid_gesture_name_is_a_clear_error():
    with pytest.raises(ConfigError, match="gesture='wave'.*choose from"):
        _make("GaussTac-Gesture-v1", gesture="wave")


@pytest.mark.parametrize("sim_backend", ["physx_cpu", "cpu"] + ([] if torch.cuda.is_available() else ["auto"]))
def test_several_envs_on_the_cpu_name_the_ways_that_work(sim_backend):
    """ManiSkill's own error here is "failed to find device cuda"."""
    with pytest.raises(ConfigError, match=r"num_envs=4 .*physx_cuda.*AsyncVectorEnv.*--ray"):
        gym.make("GaussTac-Gesture-v1", num_envs=4, sim_backend=sim_backend, obs_mode="state_dict")
    with pytest.raises(ConfigError, match="num_envs=0"):
        gym.make("GaussTac-Gesture-v1", num_envs=0, sim_backend=sim_backend, obs_mode="state_dict")


@pytest.mark.skipif(torch.cuda.is_available(), reason="the machine has CUDA")
def test_gpu_backend_without_cuda_is_a_clear_error():
    """ManiSkill's own error here is "failed to find device cuda"."""
    with pytest.raises(ConfigError, match=r"physx_cuda.*needs an NVIDIA GPU.*physx_cpu"):
        gym.make("GaussTac-Gesture-v1", num_envs=1, sim_backend="physx_cuda", obs_mode="state_dict")


def test_missing_physx_gpu_library_names_the_file(monkeypatch):
    """Where SAPIEN cannot fetch its PhysX GPU library (no internet),
    the error names the file, the URL and the folder, before ManiSkill starts.
    CUDA and the download are stubbed: this runs the check, not SAPIEN's GPU."""
    import sapien.physx

    def offline():
        raise ConnectionError("Failed to resolve 'github.com'")

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(sapien.physx, "is_gpu_enabled", lambda: False)
    monkeypatch.setattr(sapien.physx, "enable_gpu", offline)
    with pytest.raises(ConfigError, match=r"libPhysXGpu_64\.so.*ConnectionError.*linux-so\.zip.*unzip it into"):
        gym.make("GaussTac-Gesture-v1", num_envs=2, sim_backend="physx_cuda", obs_mode="state_dict")


def test_non_gausstac_robot_is_refused():
    with pytest.raises(ConfigError, match="has no GaussTac pads"):
        _make("GaussTac-Gesture-v1", robot_uids="allegro_hand_right")


def test_nan_action_is_refused_and_changes_nothing():
    env = _make("GaussTac-Gesture-v1")
    try:
        env.reset(seed=0)
        base = env.unwrapped
        q0 = base.agent.robot.get_qpos().clone()
        steps0 = int(base.elapsed_steps[0])
        a = np.zeros(env.action_space.shape, np.float32)
        a[..., 3] = np.nan
        with pytest.raises(ConfigError, match="NaN or inf"):
            env.step(a)
        assert torch.equal(base.agent.robot.get_qpos(), q0)
        assert int(base.elapsed_steps[0]) == steps0
        env.step(np.zeros_like(a))  # still usable
    finally:
        env.close()


def test_sponge_material_is_user_settable_and_checked():
    """(2 mm grid: the stiff sponge's explicit substeps at 1 mm took 5 minutes of the suite.)"""
    with pytest.raises(ConfigError, match="nu"):
        _make("GaussTac-SqueezeSponge-v1", sponge_nu=0.6)
    with pytest.warns(Warning, match="spans only"):
        soft = _make("GaussTac-SqueezeSponge-v1", sponge_E=1.5e4, mpm_dx=2e-3)
        stiff = _make("GaussTac-SqueezeSponge-v1", sponge_E=1.2e5, mpm_dx=2e-3)
    try:
        forces = []
        for env in (soft, stiff):
            obs, _ = env.reset(seed=2)
            expert = make_expert(env)
            expert.reset()
            for _ in range(4):  # the same approach and 1 mm indentation for both
                obs, _, _, _, info = env.step(expert.act(obs))
            forces.append(float(info["pad_force"][0]))
        assert forces[1] > 2.0 * forces[0], forces
    finally:
        soft.close()
        stiff.close()


def test_reconfiguring_every_reset_rebuilds_the_scene():
    """ManiSkill's DP/BC evaluation envs use reconfiguration_freq=1."""
    env = _make("GaussTac-PressCube-v1", reconfiguration_freq=1)
    try:
        for seed in (0, 1):
            obs, _ = env.reset(seed=seed)
            obs, *_ = env.step(np.zeros(env.action_space.shape, np.float32))
        assert sorted(env.unwrapped._rigid) == ["cube"]
    finally:
        env.close()


@pytest.mark.parametrize("gesture", ["fist", "open", "peace", "point", "spread", "thumbs_up"])
def test_every_gesture_is_reachable(gesture):
    """No gesture is blocked by self-collision: the expert reaches each one."""
    env = _make("GaussTac-Gesture-v1", gesture=gesture, control_mode="pd_joint_pos")
    try:
        obs, _ = env.reset(seed=0)
        expert = make_expert(env)
        for _ in range(20):
            obs, _, _, _, info = env.step(expert.act(obs))
            if info["success"].all():
                break
        assert info["success"].all(), info["max_joint_error"]
    finally:
        env.close()


def test_seeds_reproduce_episodes():
    env = _make("GaussTac-PressCube-v1")
    try:
        env.reset(seed=5)
        first = (env.unwrapped.target_force.clone(), env.unwrapped.face_frame.clone())
        env.reset(seed=6)
        other = env.unwrapped.target_force.clone()
        env.reset(seed=5)
        assert torch.equal(env.unwrapped.target_force, first[0])
        assert torch.equal(env.unwrapped.face_frame, first[1])
        assert not torch.equal(other, first[0])
    finally:
        env.close()
