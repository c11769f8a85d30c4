"""GaussTac agents: the Allegro pads, ``add_gausstac_pads`` errors, and the floating Ability
hand made with it (pad meshes, pad directions checked in SAPIEN, tactile obs, a press)."""
import gymnasium as gym
import numpy as np
import pytest
import torch
import trimesh

import gausstac_maniskill  # noqa: F401  (registers agents and tasks)
from gausstac_maniskill.agents import AllegroHandRightGaussTac, add_gausstac_pads
from gausstac_maniskill.agents.ability import (ABILITY_FINGER_HULL, ABILITY_PAD_LINKS, ABILITY_URDF,
                                               FloatingAbilityHandRightGaussTac, finger_hull_mesh)
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.urdf import link_mesh

ABILITY = "floating_ability_hand_right_gausstac"
PADS = ["thumb", "index", "middle", "ring", "pinky"]
Q2_MIMIC = (1.05851325, 0.72349796)  # finger q2 = a q1 + b under ManiSkill's mimic controller


def test_allegro_agent_has_four_named_pads():
    names = [p.name for p in AllegroHandRightGaussTac.gausstac_pads]
    assert names == ["thumb", "index", "middle", "ring"]
    assert AllegroHandRightGaussTac.uid == "allegro_hand_right_gausstac"


def test_unknown_link_names_the_link_and_suggests_close_names():
    with pytest.raises(ConfigError) as e:
        add_gausstac_pads("floating_ability_hand_right", ["index_L3"], register=False)
    msg = str(e.value)
    assert "'index_L3'" in msg and "did you mean" in msg and "index_L2" in msg


def test_unknown_agent_uid_is_a_config_error():
    with pytest.raises(ConfigError, match="floating_ability_hand_rigth"):
        add_gausstac_pads("floating_ability_hand_rigth", ["index_L2"], register=False)
    with pytest.raises(ConfigError, match="non-empty"):
        add_gausstac_pads("floating_ability_hand_right", [], register=False)


def test_ability_agent_is_registered_with_five_pads():
    from mani_skill.agents.registration import REGISTERED_AGENTS

    assert REGISTERED_AGENTS[ABILITY].agent_cls is FloatingAbilityHandRightGaussTac
    pads = FloatingAbilityHandRightGaussTac.gausstac_pads
    assert [p.name for p in pads] == PADS
    assert [p.link for p in pads] == [ABILITY_PAD_LINKS[n] for n in PADS]
    # a pad's axis is a unit vector perpendicular to its link's flexion axis (z)
    for p in pads:
        assert abs(np.linalg.norm(p.axis) - 1) < 1e-9 and abs(p.axis[2]) < 1e-9


def test_ability_pad_meshes_are_watertight_and_match_the_urdf():
    # the fingers' collision mesh is open; the committed pad mesh is its convex hull (+ tip sphere)
    assert not link_mesh(ABILITY_URDF, "index_L2").is_watertight
    hull = trimesh.load(ABILITY_FINGER_HULL, force="mesh")
    assert hull.is_watertight
    assert abs(hull.volume - finger_hull_mesh().volume) < 1e-3 * hull.volume
    assert np.allclose(hull.bounds, finger_hull_mesh().bounds, atol=1e-6)
    assert link_mesh(ABILITY_URDF, "thumb_L2").is_watertight  # the thumb's is used as is


@pytest.fixture(scope="module")
def ability_env(sapien_vulkan):
    env = gym.make("GaussTac-Touch-v1", robot_uids=ABILITY, obs_mode="state_dict", sim_backend="physx_cpu",
                   mpm_dx=2e-3, cube_gap=0.001)
    yield env
    env.close()


def _set_joints(u, q0, **targets):
    names = [j.name for j in u.agent.robot.get_active_joints()]
    q = q0.clone()
    for name, v in targets.items():
        q[0, names.index(name)] = v
        if name.endswith("_q1") and not name.startswith("thumb"):
            q[0, names.index(name[:-1] + "2")] = Q2_MIMIC[0] * v + Q2_MIMIC[1]
    u.agent.robot.set_qpos(q)


def test_ability_pads_face_the_closing_direction_and_the_thumb_opposes(ability_env):
    ability_env.reset(seed=0)
    u = ability_env.unwrapped
    q0 = u.agent.robot.get_qpos().clone()
    try:
        for pad in PADS:
            S0 = u.pad_frame(pad)[0].numpy()
            if pad != "thumb":  # open hand: the palm faces world +x, fingers point up
                assert S0[0, 2] > 0.9, (pad, S0[:3, 2])
            _set_joints(u, q0, **{("thumb_q2" if pad == "thumb" else f"{pad}_q1"): 0.6})
            d = u.pad_frame(pad)[0, :3, 3].numpy() - S0[:3, 3]
            assert d @ S0[:3, 2] > 0.1 * np.linalg.norm(d), (pad, d, S0[:3, 2])  # the pad side leads when closing
            _set_joints(u, q0)
        # a pinch: thumb and index pads face each other a few mm apart
        _set_joints(u, q0, thumb_q1=-0.8, thumb_q2=1.01, index_q1=1.01)
        A, B = u.pad_frame("thumb")[0].numpy(), u.pad_frame("index")[0].numpy()
        assert A[:3, 2] @ B[:3, 2] < -0.7
        assert np.linalg.norm(A[:3, 3] - B[:3, 3]) < 5e-3
    finally:
        u.agent.robot.set_qpos(q0)


def test_ability_touch_env_obs_and_press_gives_force(ability_env):
    obs, info = ability_env.reset(seed=0)
    u = ability_env.unwrapped
    assert sorted(obs["tactile"]) == sorted(PADS)
    for pad in PADS:
        m = obs["tactile"][pad]
        assert m["depth"].shape == (1, 16, 16) and m["depth"].dtype == torch.float32
        assert m["shear"].shape == (1, 16, 16, 2) and m["shear"].dtype == torch.float32
        assert m["force"].shape == (1, 16, 16) and m["force"].dtype == torch.float32
    assert u.touch_pad == "index" and not info["success"].any()
    # drive the floating root 2.5 mm past first contact along the index pad's normal
    n = u.pad_frame("index")[0, :3, 2].numpy()
    action = np.zeros(ability_env.action_space.shape, np.float32)  # root xyz, rpy; 4 finger q1; thumb q1, q2
    for k in range(8):
        action[:3] = min(k + 1, 4) / 4 * (u.cube_gap + 2.5e-3) * n
        obs, reward, terminated, truncated, info = ability_env.step(action)
    force = info["pad_force"].item()
    assert force > 0.05, info
    assert info["success"].all() and torch.isfinite(reward).all()
    assert obs["tactile"]["index"]["force"].sum().item() == pytest.approx(force, rel=1e-4)
    assert obs["tactile"]["index"]["depth"].max().item() > 2e-4
    assert info["pad_forces"][0, PADS.index("pinky")] == 0  # far from the cube


@pytest.mark.sapien
def test_touch_sandbox_runs_the_allegro_too():
    env = gym.make("GaussTac-Touch-v1", robot_uids="allegro_hand_right_gausstac", obs_mode="state_dict",
                   sim_backend="physx_cpu", mpm_dx=2e-3)
    try:
        obs, _ = env.reset(seed=0)
        obs, reward, *_ = env.step(np.zeros(env.action_space.shape, np.float32))
        assert sorted(obs["tactile"]) == ["index", "middle", "ring", "thumb"]
        assert env.unwrapped.touch_pad == "index" and torch.isfinite(reward).all()
        # the cube's face is parallel to the index pad, cube_gap (3 mm) in front of its apex
        S = env.unwrapped.pad_frame("index")[0].numpy()
        C = env.unwrapped.cube.pose.to_transformation_matrix()[0].double().numpy()
        assert np.allclose(C[:3, :3], S[:3, :3], atol=1e-5)
        assert (C[:3, 3] - S[:3, 3]) @ S[:3, 2] == pytest.approx(0.003 + 0.01, abs=1e-5)
    finally:
        env.close()


def test_per_link_fields_and_stray_links():
    cls = add_gausstac_pads("allegro_hand_right", {"index": "link_3.0_tip", "thumb": "link_15.0_tip"},
                            uid="test_allegro_per_link", register=False, thickness=3e-3,
                            per_link={"link_15.0_tip": {"cone_deg": 30.0}})
    pads = {p.name: p for p in cls.gausstac_pads}
    assert pads["thumb"].cone_deg == 30.0 and pads["index"].cone_deg == 60.0
    assert pads["index"].thickness == pads["thumb"].thickness == 3e-3
    with pytest.raises(ConfigError, match="without a pad"):
        add_gausstac_pads("allegro_hand_right", ["link_3.0_tip"], register=False, axes={"link_7.0_tip": (1, 0, 0)})
    with pytest.raises(ConfigError, match="colour"):
        add_gausstac_pads("allegro_hand_right", ["link_3.0_tip"], register=False,
                          per_link={"link_3.0_tip": {"colour": 1}})


def test_ability_sensor_x_runs_along_the_finger_towards_the_tip():
    from gausstac_maniskill.tactile import build_pad, pad_mesh

    for pad in FloatingAbilityHandRightGaussTac.gausstac_pads:
        tip = np.array((0.065, 0.016, 0.0) if pad.link == "thumb_L2" else (0.035, -0.018, 0.0))
        S = build_pad(pad, pad_mesh(pad, ABILITY_URDF), 1e-3, 2e-3).sensor_frame
        z = S[:3, 2]
        along = tip - (tip @ z) * z  # the tip direction within the pad plane
        assert S[:3, 0] @ along / np.linalg.norm(along) > 0.999, pad.name
        assert abs(S[:3, 0] @ z) < 1e-9
        assert abs(S[:3, 2] @ np.array([0.0, 0.0, 1.0])) < 1e-6  # (the link z is the flexion axis)
