"""Data collection (RecordEpisode h5 + json), merging, exact replay by env states, the
replay launcher and the tactile observation wrapper.

One short recording is shared by the module: PressCube (the index pad touches the cube, so
the tactile maps are non-zero) when it is registered, else Gesture (maps read zero). Its index
pad carries a small GelSight Mini image (``OPTICAL``), recorded and replayed with the maps.
"""
import shutil

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch

import gausstac_maniskill
from gausstac_maniskill.collect import CollectConfig, collect, merge_trajectories
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.experts import EXPERTS

PADS = ["thumb", "index", "middle", "ring"]


def _task() -> str:
    from mani_skill.utils.registration import REGISTERED_ENVS

    gausstac_maniskill.register()  # `import gausstac_maniskill` alone fills gymnasium's registry only
    press = "GaussTac-PressCube-v1"
    return press if press in REGISTERED_ENVS and press in EXPERTS else "GaussTac-Gesture-v1"


TASK = _task()
CONTACT = TASK != "GaussTac-Gesture-v1"
OPTICAL = {"optical": {"index": "gelsight_mini"}, "optical_width": 48}  # 48 x 48 px on the square pad
STEPS = 12  # PressCube reaches its force target (and terminates) in about 6-8 steps


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, sapien_vulkan):
    out = tmp_path_factory.mktemp("demos")
    summary = collect(CollectConfig(env_id=TASK, num_episodes=2, num_procs=1, obs_mode="rgb",
                                    control_mode="pd_joint_delta_pos", seed=3, out=str(out),
                                    max_episode_steps=STEPS, mpm_dx=2e-3, progress=False, env_kwargs=OPTICAL))
    return summary


def _load_json(path):
    from mani_skill.utils.io_utils import load_json

    return load_json(str(path).replace(".h5", ".json"))


def test_collect_writes_h5_and_json_with_tactile_rgb_and_mpm_state(recorded):
    path = recorded["path"]
    assert path.endswith(f"{TASK}/trajectory.rgb.pd_joint_delta_pos.physx_cpu.h5")
    assert recorded["episodes"] == 2 and recorded["attempted"] == 2 and recorded["steps"] > 0
    meta = _load_json(path)
    assert meta["env_info"]["env_id"] == TASK
    assert meta["env_info"]["env_kwargs"]["mpm_dx"] == 2e-3
    assert meta["env_info"]["env_kwargs"]["pad_solver"] == "fem"  # the default, resolved: the cube is rigid
    assert [e["episode_id"] for e in meta["episodes"]] == [0, 1]
    assert [e["episode_seed"] for e in meta["episodes"]] == [3, 4]
    with h5py.File(path, "r") as f:
        assert sorted(f) == ["traj_0", "traj_1"]
        for name, ep in zip(("traj_0", "traj_1"), meta["episodes"]):
            g = f[name]
            T = ep["elapsed_steps"]
            assert 1 <= T <= STEPS and g["actions"].shape == (T, 16)
            assert sorted(g["obs/tactile"]) == sorted(PADS)
            for pad in PADS:
                assert g[f"obs/tactile/{pad}/depth"].shape == (T + 1, 16, 16)
                assert g[f"obs/tactile/{pad}/shear"].shape == (T + 1, 16, 16, 2)
                assert g[f"obs/tactile/{pad}/force"].shape == (T + 1, 16, 16)
                assert g[f"obs/tactile/{pad}/force"].dtype == np.float32
            assert g["obs/tactile/index/rgb"].shape == (T + 1, 48, 48, 3) and g["obs/tactile/index/rgb"].dtype == np.uint8
            assert g["obs/tactile/index/markers"].shape[::2] == (T + 1, 2)
            assert "rgb" not in g["obs/tactile/thumb"]  # an optical sensor on the index pad only
            rgb = g["obs/sensor_data/splat_camera/rgb"]
            assert rgb.shape == (T + 1, 128, 128, 3) and rgb.dtype == np.uint8
            assert g["env_states/gausstac/link_pose"].shape[0] == T + 1
            assert g["env_states/gausstac/link_pose"].compression == "gzip"  # merged files are compressed
            if CONTACT:
                assert np.abs(g["obs/tactile/index/force"][()]).sum() > 0.1
                assert ep["success"]


def test_merge_renumbers_trajectories_in_seed_order(recorded, tmp_path):
    src = recorded["path"]
    out = tmp_path / "merged.h5"
    merged = merge_trajectories(out, [src, src])
    assert [e["episode_id"] for e in merged["episodes"]] == [0, 1, 2, 3]
    assert [e["episode_seed"] for e in merged["episodes"]] == [3, 3, 4, 4]
    assert _load_json(out)["episodes"] == merged["episodes"]
    with h5py.File(out, "r") as f, h5py.File(src, "r") as s:
        assert sorted(f) == ["traj_0", "traj_1", "traj_2", "traj_3"]
        for new, old in (("traj_1", "traj_0"), ("traj_2", "traj_1")):
            np.testing.assert_array_equal(f[new]["obs/tactile/index/depth"][()], s[old]["obs/tactile/index/depth"][()])
            np.testing.assert_array_equal(f[new]["env_states/gausstac/link_pose"][()],
                                          s[old]["env_states/gausstac/link_pose"][()])
    # ManiSkill's own merger reads the same files
    from mani_skill.trajectory.merge_trajectory import merge_trajectories as ms_merge

    ms_merge(str(tmp_path / "ms.h5"), [src, src])
    with h5py.File(tmp_path / "ms.h5", "r") as f:
        assert sorted(f) == ["traj_0", "traj_1", "traj_2", "traj_3"]
    # files of another env are refused
    other = tmp_path / "other.h5"
    shutil.copy(src, other)
    meta = _load_json(src)
    meta["env_info"]["env_id"] = "Other-v1"
    from mani_skill.utils.io_utils import dump_json

    dump_json(str(tmp_path / "other.json"), meta)
    with pytest.raises(ConfigError, match="refusing to merge"):
        merge_trajectories(tmp_path / "bad.h5", [src, other])


def test_replay_by_env_states_reproduces_tactile_and_rgb_exactly(recorded):
    """For every recorded step t: reset, set_state_dict(env_states[t]) -> the same tactile
    maps (bit-exact) and the same splat-camera image as recorded."""
    from mani_skill.trajectory import utils as trajectory_utils

    meta = _load_json(recorded["path"])
    env = gym.make(TASK, **meta["env_info"]["env_kwargs"])
    try:
        with h5py.File(recorded["path"], "r") as f:
            touched = 0.0
            for ep in meta["episodes"]:
                g = f[f"traj_{ep['episode_id']}"]
                states = trajectory_utils.dict_to_list_of_dicts(g["env_states"])  # as ManiSkill's replay
                for t, state in enumerate(states):
                    env.reset(seed=ep["episode_seed"])
                    env.unwrapped.set_state_dict(state)  # one env, no env axis: as ManiSkill's replay
                    obs = env.unwrapped.get_obs(unflattened=True)
                    for pad in PADS:
                        for key in ("depth", "shear", "force"):
                            want = g[f"obs/tactile/{pad}/{key}"][t]
                            got = obs["tactile"][pad][key][0].numpy()
                            assert np.array_equal(got, want), (ep["episode_id"], t, pad, key)
                    for key in ("rgb", "markers"):  # the index pad's optical image and markers
                        want = g[f"obs/tactile/index/{key}"][t]
                        assert np.array_equal(obs["tactile"]["index"][key][0].numpy(), want), (ep["episode_id"], t, key)
                    touched += float(np.abs(obs["tactile"]["index"]["force"][0].numpy()).sum())
                    rgb = obs["sensor_data"]["splat_camera"]["rgb"][0].numpy()
                    assert np.array_equal(rgb, g["obs/sensor_data/splat_camera/rgb"][t]), (ep["episode_id"], t)
            if CONTACT:
                assert touched > 0.1  # the comparison covered non-zero maps
    finally:
        env.close()


def test_replay_launcher_by_env_states_and_its_overwrite_guard(recorded, tmp_path, capsys):
    from gausstac_maniskill import replay

    src = tmp_path / "trajectory.rgb.pd_joint_delta_pos.physx_cpu.h5"
    shutil.copy(recorded["path"], src)
    shutil.copy(recorded["path"].replace(".h5", ".json"), str(src).replace(".h5", ".json"))
    # same obs mode and control mode: ManiSkill would truncate the source; the launcher refuses
    assert replay.main(["--traj-path", str(src), "--save-traj"]) == 2
    assert "file being replayed" in capsys.readouterr().err
    with h5py.File(src, "r") as f:
        assert "traj_0" in f
    # ManiSkill's action conversion needs arm/gripper controllers: refused up front
    assert replay.main(["--traj-path", str(src), "-c", "pd_joint_pos", "-o", "state_dict"]) == 2
    assert "arm" in capsys.readouterr().err
    rc = replay.main(["--traj-path", str(src), "--use-env-states", "-o", "state_dict", "--save-traj",
                      "--allow-failure", "--count", "1"])
    assert rc == 0
    out = tmp_path / "trajectory.state_dict.pd_joint_delta_pos.physx_cpu.h5"
    with h5py.File(out, "r") as f, h5py.File(src, "r") as s:
        assert sorted(f) == ["traj_0"]
        assert "sensor_data" not in f["traj_0/obs"]
        for pad in PADS:
            np.testing.assert_array_equal(f[f"traj_0/obs/tactile/{pad}/force"][()],
                                          s[f"traj_0/obs/tactile/{pad}/force"][()])


def _copy_trajectory(src, dst) -> None:
    shutil.copy(src, dst)
    shutil.copy(str(src).replace(".h5", ".json"), str(dst).replace(".h5", ".json"))


def _bytes(*paths) -> list[bytes]:
    return [open(p, "rb").read() for p in paths]


def test_replay_refuses_to_overwrite_an_existing_file_unless_told(recorded, tmp_path, capsys, monkeypatch):
    """ManiSkill names the replay's output <name>.<obs_mode>.<control_mode>.<backend>.h5 next to
    the source, where a collection of that name may already be: the launcher refuses before
    writing anything (the files stay byte-identical); --overwrite replaces them."""
    from gausstac_maniskill import cli, replay

    src = tmp_path / "trajectory.rgb.pd_joint_delta_pos.physx_cpu.h5"
    _copy_trajectory(recorded["path"], src)
    # an earlier state_dict collection, under the name the replay below writes
    old = tmp_path / "trajectory.state_dict.pd_joint_delta_pos.physx_cpu.h5"
    old_json = tmp_path / "trajectory.state_dict.pd_joint_delta_pos.physx_cpu.json"
    with h5py.File(old, "w") as f:
        f["traj_0/actions"] = np.arange(6.0).reshape(3, 2)
        f["traj_9/actions"] = np.zeros((1, 2))
    old_json.write_text('{"env_info": {}, "episodes": []}')
    before = _bytes(old, old_json, src)
    argv = ["--traj-path", str(src), "--use-env-states", "-o", "state_dict", "--save-traj", "--allow-failure",
            "--count", "1"]
    assert replay.main(argv) == 2
    err = capsys.readouterr().err
    assert str(old) in err and str(old_json) in err and "--overwrite" in err and "nothing was written" in err
    monkeypatch.setattr("multiprocessing.set_start_method", lambda *a, **k: None)  # cli's, for the -n workers
    assert cli.main(["replay", *argv]) == 2  # `gausstac replay`: the same launcher
    assert str(old) in capsys.readouterr().err
    # the .json alone, a worker's file of -n 2 (merged, then deleted), a video: refused the same way
    old.rename(tmp_path / "moved.h5")
    assert replay.main(argv) == 2 and str(old_json) in capsys.readouterr().err
    old_json.rename(tmp_path / "moved.json")
    worker = tmp_path / "trajectory.state_dict.pd_joint_delta_pos.physx_cpu.1.json"
    worker.write_text("{}")
    assert replay.main([*argv, "-n", "2"]) == 2 and str(worker) in capsys.readouterr().err
    assert worker.read_text() == "{}"
    video = tmp_path / "0.mp4"
    video.write_bytes(b"video")
    assert replay.main(["--traj-path", str(src), "--use-env-states", "--save-video", "--count", "1"]) == 2
    assert str(video) in capsys.readouterr().err and video.read_bytes() == b"video"
    # -n 2 workers on the CPU would write each other's 0.mp4, 1.mp4
    assert replay.main(["--traj-path", str(src), "--use-env-states", "--save-video", "-n", "2",
                        "--overwrite"]) == 2
    assert "overwrite each other's" in capsys.readouterr().err
    # the source itself: refused even with --overwrite
    assert replay.main(["--traj-path", str(src), "--save-traj", "--overwrite"]) == 2
    assert "file being replayed" in capsys.readouterr().err
    (tmp_path / "moved.h5").rename(old)
    (tmp_path / "moved.json").rename(old_json)
    assert _bytes(old, old_json, src) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([src.name, src.with_suffix(".json").name, old.name,
                                                                old_json.name, worker.name, video.name])
    # --overwrite: the replay replaces the old collection
    assert replay.main([*argv, "--overwrite"]) == 0
    with h5py.File(old, "r") as f, h5py.File(src, "r") as s:
        assert sorted(f) == ["traj_0"] and "sensor_data" not in f["traj_0/obs"]
        np.testing.assert_array_equal(f["traj_0/obs/tactile/index/force"][()], s["traj_0/obs/tactile/index/force"][()])
    assert _load_json(old)["env_info"]["env_kwargs"]["obs_mode"] == "state_dict"
    assert _bytes(src) == before[2:]


def test_replay_outputs_follow_maniskills_naming(recorded, tmp_path):
    from mani_skill.trajectory import replay_trajectory

    from gausstac_maniskill.replay import replay_outputs, replayed_path

    src = tmp_path / "demo.h5"  # a name without ManiSkill's suffixes
    _copy_trajectory(recorded["path"], src)

    def outputs(*argv):
        return [p.replace(str(tmp_path) + "/", "") for p in replay_outputs(
            replay_trajectory.parse_args(["--traj-path", str(src), *argv]))]

    assert outputs() == [] and outputs("-n", "2") == []
    assert outputs("--save-traj") == ["demo.rgb.pd_joint_delta_pos.physx_cpu.h5",
                                      "demo.rgb.pd_joint_delta_pos.physx_cpu.json"]
    assert outputs("--save-traj", "-o", "state", "-n", "2", "-b", "cpu")[2:] == [
        "demo.state.pd_joint_delta_pos.physx_cpu.0.h5", "demo.state.pd_joint_delta_pos.physx_cpu.0.json",
        "demo.state.pd_joint_delta_pos.physx_cpu.1.h5", "demo.state.pd_joint_delta_pos.physx_cpu.1.json"]
    assert outputs("--save-traj", "-b", "physx_cuda", "-n", "2")[:1] == ["demo.rgb.pd_joint_delta_pos.physx_cuda.h5"]
    assert outputs("--save-video") == ["0.mp4", "1.mp4"] and outputs("--save-video", "--count", "1") == ["0.mp4"]
    args = replay_trajectory.parse_args(["--traj-path", str(src), "--save-traj", "-o", "state_dict"])
    assert replayed_path(args) == str(tmp_path / "demo.state_dict.pd_joint_delta_pos.physx_cpu.h5")
    # a file whose env_kwargs name no modes: the env's defaults (BaseEnv: "state"; the hand's first controller)
    from mani_skill.utils.io_utils import dump_json

    meta = _load_json(src)
    for key in ("obs_mode", "control_mode"):
        meta["env_info"]["env_kwargs"].pop(key)
    dump_json(str(src.with_suffix(".json")), meta)
    assert outputs("--save-traj")[0] == "demo.state.pd_joint_delta_pos.physx_cpu.h5"


def test_collect_refuses_to_overwrite_an_existing_collection_unless_told(recorded, tmp_path, monkeypatch):
    """collect checks its output names before recording anything; --overwrite replaces them.
    The workers are replaced by a copy of the module's recording (what they would write)."""
    import dataclasses

    from gausstac_maniskill import collect as collect_mod
    from gausstac_maniskill.collect import existing_outputs, output_path

    calls = []

    def fake_worker(cfg, worker, h5_path, report):
        calls.append(worker)
        _copy_trajectory(recorded["path"], h5_path)

    monkeypatch.setattr(collect_mod, "_run_worker", fake_worker)
    cfg = CollectConfig(env_id=TASK, num_episodes=2, obs_mode="rgb", seed=3, out=str(tmp_path), progress=False)
    out = output_path(cfg)
    out.parent.mkdir(parents=True)
    with h5py.File(out, "w") as f:  # an earlier collection
        f["traj_0/actions"] = np.arange(6.0).reshape(3, 2)
    out.with_suffix(".json").write_text('{"env_info": {}, "episodes": []}')
    before = _bytes(out, out.with_suffix(".json"))
    assert existing_outputs(cfg) == [out, out.with_suffix(".json")]
    with pytest.raises(ConfigError, match=r"already exist.*nothing was recorded.*--overwrite"):
        collect(cfg)
    assert calls == [] and _bytes(out, out.with_suffix(".json")) == before
    assert sorted(p.name for p in out.parent.iterdir()) == sorted([out.name, out.with_suffix(".json").name])
    # the .json alone, or a video of a seed it may record (-o state_dict: another .h5 name), likewise
    out.rename(tmp_path / "moved.h5")
    with pytest.raises(ConfigError, match=out.with_suffix(".json").name):
        collect(cfg)
    (tmp_path / "moved.h5").rename(out)
    video = out.parent / "videos" / "seed4.mp4"
    video.parent.mkdir()
    video.write_bytes(b"video")
    with pytest.raises(ConfigError, match="seed4.mp4"):
        collect(dataclasses.replace(cfg, obs_mode="state_dict", save_video=True))
    assert calls == [] and video.read_bytes() == b"video"
    # merge_trajectories itself refuses an existing output
    with pytest.raises(ConfigError, match="exist"):
        merge_trajectories(out, [recorded["path"]])
    assert _bytes(out, out.with_suffix(".json")) == before
    # --overwrite: recorded again, the old collection replaced
    assert collect_mod.main([TASK, "-n", "2", "-s", "3", "--out", str(tmp_path), "--no-progress"]) == 2
    assert calls == []
    summary = collect(dataclasses.replace(cfg, overwrite=True))
    assert calls == [0] and summary["episodes"] == 2 and summary["path"] == str(out)
    with h5py.File(out, "r") as f:
        assert sorted(f) == ["traj_0", "traj_1"] and f["traj_0/actions"].shape[1] == 16
    assert [e["episode_seed"] for e in _load_json(out)["episodes"]] == [3, 4]
    assert video.read_bytes() == b"video"


def test_recorded_env_kwargs_give_the_eval_env_the_recorded_physics(recorded, tmp_path):
    from gausstac_maniskill.obs_wrappers import recorded_env_kwargs

    kw = recorded_env_kwargs(recorded["path"])
    assert kw["mpm_dx"] == 2e-3  # recorded with --mpm-dx 2e-3: the default (1e-3) would step other physics
    assert not {"obs_mode", "control_mode", "sim_backend", "render_mode", "num_envs"} & set(kw)
    env = gym.make(TASK, obs_mode="state_dict", **kw)
    try:
        assert env.unwrapped.mpm_settings.dx == 2e-3
    finally:
        env.close()
    with pytest.raises(ConfigError, match="not found"):
        recorded_env_kwargs(tmp_path / "none.h5")
    (tmp_path / "bare.json").write_text("{}")
    with pytest.raises(ConfigError, match="env_kwargs"):
        recorded_env_kwargs(tmp_path / "bare.h5")


def test_obs_wrapper_shapes_and_loader_match_the_live_env(recorded, tmp_path):
    from mani_skill.utils.wrappers.flatten import FlattenRGBDObservationWrapper

    from gausstac_maniskill.obs_wrappers import (TactileLayout, TactileObsWrapper, flatten_file, load_demos,
                                                 tactile_state_obs_extractor)

    data = load_demos(recorded["path"])
    n = recorded["steps"]
    assert data["tactile"].shape == (n, 4096) and data["tactile"].dtype == np.float32
    assert data["actions"].shape == (n, 16) and data["rgb"].shape == (n, 128, 128, 3)
    assert data["optical/index"].shape == (n, 48, 48, 3) and data["optical/index"].dtype == np.uint8
    assert data["markers/index"].shape[::2] == (n, 2) and "optical/thumb" not in data
    assert data["state"].shape[0] == n and data["state"].shape[1] > 4096
    assert TactileLayout(pool=4).size(4) == 256 and TactileLayout(fields=("force",)).size(4) == 1024

    meta = _load_json(recorded["path"])
    seed = meta["episodes"][0]["episode_seed"]
    env = gym.make(TASK, **meta["env_info"]["env_kwargs"])
    try:
        flat = FlattenRGBDObservationWrapper(TactileObsWrapper(env))
        assert flat.unwrapped.single_observation_space["state"].shape == (data["state"].shape[1],)
        obs, _ = flat.reset(seed=seed)
        assert obs["state"].shape == (1, data["state"].shape[1]) and obs["rgb"].shape == (1, 128, 128, 3)
        # the live state (agent, extra, tactile) is the loader's first row of that episode
        np.testing.assert_array_equal(obs["state"][0].numpy(), data["state"][0])
        np.testing.assert_array_equal(obs["rgb"][0].numpy(), data["rgb"][0])
        # the diffusion-policy extractor on the raw recorded obs gives the same vector
        with h5py.File(recorded["path"], "r") as f:
            from mani_skill.trajectory.dataset import load_h5_data

            raw = load_h5_data(f["traj_0/obs"])
        row = np.hstack([np.asarray(x, np.float32).reshape(len(x), -1) for x in tactile_state_obs_extractor()(raw)])
        np.testing.assert_array_equal(row[0], data["state"][0])
    finally:
        env.close()

    env = gym.make(TASK, obs_mode="state_dict", sim_backend="physx_cpu", mpm_dx=2e-3)
    try:
        img = TactileObsWrapper(env, layout="image", pool=2)
        obs, _ = img.reset(seed=0)
        assert obs["tactile"].shape == (1, 8, 8, 16) and obs["tactile"].dtype == torch.float32
        vec = TactileObsWrapper(gym.make(TASK, obs_mode="state_dict", sim_backend="physx_cpu", mpm_dx=2e-3),
                                flatten=True, pads=["index"], pool=4)
        obs, _ = vec.reset(seed=seed)
        agent_extra = sum(int(np.prod(v.shape[1:])) for k in ("agent", "extra")
                          for v in env.unwrapped.get_obs(unflattened=True)[k].values())
        assert obs.shape == (1, agent_extra + 64) == (1, vec.unwrapped.single_observation_space.shape[0])
        vec.close()
        # the flattened copy of the file (for state-based baselines) starts with that same vector
        info = flatten_file(recorded["path"], str(tmp_path / "flat.h5"), pads=["index"], pool=4)
        assert info == {"traj": 2, "obs_dim": agent_extra + 64}
        with h5py.File(tmp_path / "flat.h5", "r") as f:
            np.testing.assert_array_equal(f["traj_0/obs"][0], obs[0].numpy())
            assert f["traj_0/actions"].shape[0] == f["traj_0/obs"].shape[0] - 1
    finally:
        env.close()


def test_collect_refuses_unknown_env_and_bad_arguments(tmp_path):
    with pytest.raises(ConfigError, match="unknown env id"):
        collect(CollectConfig(env_id="NoSuchEnv-v1", out=str(tmp_path)))
    with pytest.raises(ConfigError, match="num-episodes"):
        collect(CollectConfig(env_id=TASK, num_episodes=0, out=str(tmp_path)))
    with pytest.raises(ConfigError, match="fields"):
        from gausstac_maniskill.obs_wrappers import TactileLayout

        TactileLayout(fields=("pressure",))


@pytest.mark.slow
@pytest.mark.sapien
def test_two_worker_processes_merge_in_seed_order(tmp_path):
    """Spawned workers (one env each); the merged file lists seeds 0..3 whichever worker
    recorded them. Slow: spawning + (first time on a machine) Taichi compiling for the
    workers' thread count."""
    summary = collect(CollectConfig(env_id="GaussTac-Gesture-v1", num_episodes=4, num_procs=2, out=str(tmp_path),
                                    max_episode_steps=2, progress=False))
    meta = _load_json(summary["path"])
    assert [e["episode_seed"] for e in meta["episodes"]] == [0, 1, 2, 3]
    assert [e["episode_id"] for e in meta["episodes"]] == [0, 1, 2, 3]
    assert summary["num_procs"] == 2 and summary["attempted"] == 4
    assert not list(tmp_path.rglob("worker*.h5"))  # worker files removed after the merge


def _h5_items(path) -> dict:
    """Every dataset of an h5 file: name -> array."""
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, item: out.__setitem__(name, item[()]) if isinstance(item, h5py.Dataset) else None)
    return out


@pytest.mark.sapien
def test_ray_collection_equals_a_single_process_one(tmp_path):
    """``collect --ray``: two workers as tasks of a local 2-CPU Ray instance write the same
    merged file (every dataset, bit for bit) and json episodes as one process recording
    the same seeds. Ray is installed by ``make setup`` (the ``ray`` extra)."""
    ray = pytest.importorskip("ray")
    kw = dict(env_id="GaussTac-Gesture-v1", num_episodes=2, obs_mode="state_dict", max_episode_steps=3,
              mpm_dx=2e-3, seed=5, progress=False)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        via_ray = collect(CollectConfig(**kw, num_procs=2, ray="local", out=str(tmp_path / "ray")))
        assert ray.is_initialized()  # collect leaves a Ray instance it did not start running
    finally:
        ray.shutdown()
    single = collect(CollectConfig(**kw, num_procs=1, out=str(tmp_path / "one")))
    assert via_ray["num_procs"] == 2 and via_ray["attempted"] == 2 and via_ray["steps"] == single["steps"] > 0
    assert _load_json(via_ray["path"])["episodes"] == _load_json(single["path"])["episodes"]
    a, b = _h5_items(via_ray["path"]), _h5_items(single["path"])
    assert sorted(a) == sorted(b) and any(k.startswith("traj_1/") for k in a)
    for name in a:
        assert np.array_equal(a[name], b[name], equal_nan=a[name].dtype.kind == "f"), name  # NaN: no friction hold


def test_ray_without_ray_installed_or_unreachable_is_a_clear_error(tmp_path, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_ray(name, *args, **kwargs):
        if name == "ray" or name.startswith("ray."):
            raise ImportError("No module named 'ray'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    with pytest.raises(ConfigError, match=r"--ray needs Ray: pip install"):
        collect(CollectConfig(env_id="GaussTac-Gesture-v1", num_episodes=1, ray="local", out=str(tmp_path),
                              progress=False))
