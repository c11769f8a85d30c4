"""Pose sources: MuJoCo and SAPIEN agree on the Allegro's link poses; MuJoCo tracks
position targets; bad names, paths and values fail with errors that name them."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from gausstac_maniskill.errors import AssetError, ConfigError, SimulationError
from gausstac_maniskill.pose import (ALLEGRO_TIP_LINKS, MujocoPoseSource, PoseSource,
                                     SapienPoseSource)
from gausstac_maniskill.transforms import make_pose, rotation_about


@pytest.fixture(scope="module")
def mj():
    return MujocoPoseSource()


@pytest.fixture(scope="module")
def maniskill_env(sapien_vulkan):
    """One ManiSkill env with the Allegro right hand (physx_cpu), shared by the module."""
    gym = pytest.importorskip("gymnasium")
    pytest.importorskip("mani_skill")
    import mani_skill.envs  # noqa: F401  (registers the envs)

    env = gym.make("Empty-v1", robot_uids="allegro_hand_right", obs_mode="state",
                   render_mode=None, sim_backend="physx_cpu")
    env.reset(seed=0)
    yield env
    env.close()


def random_in_limits(limits: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    lo, hi = limits[:, 0], limits[:, 1]
    return lo + (hi - lo) * rng.uniform(0.0, 1.0, size=len(lo))


# --- MuJoCo vs SAPIEN ------------------------------------------------------------
def test_mujoco_and_sapien_agree_on_link_poses(mj, maniskill_env):
    import sapien

    sp = SapienPoseSource(maniskill_env)
    robot = sp.robot
    assert sorted(sp.joint_names) == sorted(mj.joint_names)
    to_sapien = [mj.joint_names.index(n) for n in sp.joint_names]  # map joints by name
    np.testing.assert_allclose(sp.joint_limits, mj.joint_limits[to_sapien], atol=1e-6)
    common = [n for n in mj.link_names if n in sp.link_names]
    assert set(ALLEGRO_TIP_LINKS) <= set(common) and len(common) == len(sp.link_names)

    # A non-trivial root pose: MuJoCo's base is set to the root pose SAPIEN reports.
    quat = np.array([0.8, 0.1, -0.3, 0.5]) / np.linalg.norm([0.8, 0.1, -0.3, 0.5])
    robot.set_root_pose(sapien.Pose([0.1, -0.2, 0.5], quat))
    base = sp.link_poses(["base_link"])[0, 0].double()
    np.testing.assert_allclose(base[:3, 3].numpy(), [0.1, -0.2, 0.5], atol=1e-6)
    mj.set_base_pose(base)

    rng = np.random.default_rng(1234)
    max_dp = max_dR = 0.0
    for _ in range(4):
        q = random_in_limits(mj.joint_limits, rng)
        mj.set_joint_positions(q)
        robot.set_qpos(torch.as_tensor(q[to_sapien], dtype=torch.float32)[None])
        np.testing.assert_allclose(robot.get_qpos()[0].numpy(), q[to_sapien], atol=1e-6)
        T_mj = mj.link_poses(common)[0].numpy()
        T_sp = sp.link_poses(common)[0].double().numpy()
        max_dp = max(max_dp, np.abs(T_mj[:, :3, 3] - T_sp[:, :3, 3]).max())
        max_dR = max(max_dR, np.abs(T_mj[:, :3, :3] - T_sp[:, :3, :3]).max())
        tips = [common.index(n) for n in ALLEGRO_TIP_LINKS]
        np.testing.assert_allclose(T_mj[tips, :3, 3], T_sp[tips, :3, 3], atol=1e-5)
        np.testing.assert_allclose(T_mj[tips, :3, :3], T_sp[tips, :3, :3], atol=1e-5)
    print(f"\nMuJoCo vs SAPIEN, all {len(common)} links: max |dp| = {max_dp:.2e} m, "
          f"max |dR| = {max_dR:.2e}")
    assert max_dp < 1e-5 and max_dR < 1e-5


def test_sapien_source_accepts_env_agent_or_articulation(maniskill_env):
    agent = maniskill_env.unwrapped.agent
    for obj in (maniskill_env, agent, agent.robot):
        sp = SapienPoseSource(obj)
        assert isinstance(sp, PoseSource) and sp.num_envs == 1
        T = sp.link_poses(ALLEGRO_TIP_LINKS)
        assert T.shape == (1, 4, 4, 4) and torch.isfinite(T).all()
        assert sp.joint_limits.shape == (16, 2)
        assert sp.joint_names[:4] == ["joint_0.0", "joint_4.0", "joint_8.0", "joint_12.0"]
    with pytest.raises(ConfigError, match="link_3.0_tip"):
        sp.link_poses(["link_3_tip"])
    with pytest.raises(ConfigError, match="Articulation"):
        SapienPoseSource(object())


# --- MuJoCo on its own -------------------------------------------------------------
def test_mujoco_interface(mj):
    assert isinstance(mj, PoseSource) and mj.num_envs == 1
    assert len(mj.joint_names) == 16 and mj.joint_limits.shape == (16, 2)
    assert set(ALLEGRO_TIP_LINKS) <= set(mj.link_names)
    T = mj.link_poses(ALLEGRO_TIP_LINKS)
    assert T.shape == (1, 4, 4, 4) and T.dtype == torch.float64
    R = T[0, :, :3, :3]
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(4, 3, 3))
    assert mj.link_poses().shape == (1, len(mj.link_names), 4, 4)


def test_base_pose_moves_every_link_rigidly():
    src = MujocoPoseSource()
    src.set_joint_positions({"joint_1.0": 0.5, "joint_13.0": 0.7})
    T0 = src.link_poses().numpy()[0]
    B = make_pose([0.3, 0.1, -0.2], rotation_about([1, 2, 3], 0.9))
    src.set_base_pose(B)
    np.testing.assert_allclose(src.link_poses().numpy()[0], B @ T0, atol=1e-12)
    np.testing.assert_allclose(src.link_poses(["base_link"]).numpy()[0, 0], B, atol=1e-12)


@pytest.mark.parametrize("gravity_compensation", [True, False])
def test_position_control_tracks_target(gravity_compensation):
    src = MujocoPoseSource(gravity_compensation=gravity_compensation)
    rng = np.random.default_rng(0)
    target = random_in_limits(src.joint_limits, rng)
    src.set_joint_targets(target)
    tip_before = src.link_poses(["link_3.0_tip"]).clone()
    src.step(int(round(1.0 / src.model.opt.timestep)))  # 1 s
    q = src.joint_positions()
    assert np.all(np.isfinite(q)) and torch.isfinite(src.link_poses()).all()
    assert np.abs(q - target).max() < 0.05
    assert not torch.allclose(src.link_poses(["link_3.0_tip"]), tip_before)


def test_dict_targets_update_only_named_joints():
    src = MujocoPoseSource()
    before = src.joint_targets()
    src.set_joint_targets({"joint_5.0": 1.0, "joint_0.0": 9.0})  # 9 rad is clipped
    after = src.joint_targets()
    i5, i0 = src.joint_names.index("joint_5.0"), src.joint_names.index("joint_0.0")
    assert after[i5] == 1.0 and after[i0] == pytest.approx(src.joint_limits[i0, 1])
    others = np.ones(16, bool)
    others[[i5, i0]] = False
    np.testing.assert_array_equal(after[others], before[others])


def test_unstable_gains_raise_instead_of_silently_resetting(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo appends its warning to ./MUJOCO_LOG.TXT
    src = MujocoPoseSource(kp=1e4)
    src.set_joint_targets(random_in_limits(src.joint_limits, np.random.default_rng(3)))
    with pytest.raises(SimulationError, match="kp"):
        src.step(200)


# --- bad inputs ------------------------------------------------------------------
def test_wrong_link_name_suggests_close_matches(mj):
    with pytest.raises(ConfigError, match=r"link_15_tip.*did you mean.*'link_15\.0_tip'"):
        mj.link_poses(["link_15_tip"])


def test_missing_urdf_names_the_path(tmp_path):
    missing = tmp_path / "no_such_hand.urdf"
    with pytest.raises(AssetError, match="no_such_hand.urdf"):
        MujocoPoseSource(urdf_path=missing)


def test_malformed_urdf_names_the_file(tmp_path):
    bad = tmp_path / "broken.urdf"
    bad.write_text("<robot name='x'><link name='a'><joint></robot>")
    with pytest.raises(AssetError, match="broken.urdf"):
        MujocoPoseSource(urdf_path=bad)


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_target_names_the_joint(mj, bad):
    q = np.zeros(16)
    q[mj.joint_names.index("joint_6.0")] = bad
    with pytest.raises(ConfigError, match="joint_6.0"):
        mj.set_joint_targets(q)
    with pytest.raises(ConfigError, match="joint_9.0"):
        mj.set_joint_targets({"joint_9.0": bad})
    with pytest.raises(ConfigError, match="joint_9.0"):
        mj.set_joint_positions({"joint_9.0": bad})


def test_wrong_joint_name_and_shape(mj):
    with pytest.raises(ConfigError, match="joint_1.0"):
        mj.set_joint_targets({"joint_1": 0.2})
    with pytest.raises(ConfigError, match=r"\(16,\)"):
        mj.set_joint_targets(np.zeros(15))
    with pytest.raises(ConfigError, match="kp"):
        MujocoPoseSource(kp=-1.0)
