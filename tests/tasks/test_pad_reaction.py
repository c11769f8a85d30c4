"""Pad reaction on the links (``pad_reaction``): a finger pressed into
a fixed cube yields to its pad's push until its drives balance the pad; without the
reaction it is held where its drive puts it and crushes the pad. The reaction folded into
the drives holds at ManiSkill's 100 Hz where the explicit coupling needs 2000 Hz."""
import gymnasium as gym
import numpy as np
import pytest
import torch

import gausstac_maniskill  # noqa: F401  (registers agents and tasks)
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.tasks.base import PAD_REACTION_MIN_FREQ
from gausstac_maniskill.tasks.joint_contact import JointContact

pytestmark = pytest.mark.sapien


def _press(reaction, steps: int = 6, sim_freq: int = 100):
    """The Allegro index finger closes on a fixed cube 1 mm in front of its pad: its three
    flexion joints' absolute targets are 0.01 rad past their start (``pd_joint_pos``).
    Returns (index pad force per step [N], env)."""
    env = gym.make("GaussTac-Touch-v1", obs_mode="state_dict", sim_backend="physx_cpu", mpm_dx=2e-3,
                   cube_gap=1e-3, control_mode="pd_joint_pos", pad_reaction=reaction,
                   sim_config=dict(sim_freq=sim_freq))
    env.reset(seed=0)
    u = env.unwrapped
    action = u.agent.robot.get_qpos()[0, u.action_joint_index].numpy().copy()
    names = u.agent.controller.config.joint_names
    action[[names.index(f"joint_{j}.0") for j in (1, 2, 3)]] += 0.01
    forces = []
    for _ in range(steps):
        env.step(action)
        forces.append(u.pad_force("index").item())
    return forces, env


def test_finger_pressed_on_a_cube_settles_where_its_drives_balance_its_pad():
    """Point 3: the pad force is what the drives exert at the fingertip. At rest the PD
    torques kp (q* - q) of the index finger's joints equal the pad's wrench mapped through
    the finger's Jacobian (checked against SAPIEN's kinematics in test_jacobian_...):
    measured 0.03 % at 5.62 N. (This checks that PhysX brought the finger to the statics
    of its drives against the MPM reaction; the same balance failed by 10-100x with a PhysX
    spring or an explicit force, bench drive_contact.)"""
    forces, env = _press(reaction=True)  # SAPIEN at 100 Hz
    try:
        u = env.unwrapped
        assert u.mpm_every_sim_step
        robot = u.agent.robot
        art = robot._objs[0]
        link = u.pad_geometry("index").spec.link
        i = u.pad_links.index(link)
        q = art.qpos.astype(np.float64)
        target = robot.get_drive_targets()[0].numpy().astype(np.float64)  # the controller's, restored
        kp = np.array([j.stiffness for j in art.get_active_joints()])
        hand = JointContact(art, [robot.links_map[link]._objs[0]])
        hand.model.compute_full_jacobian(q)
        J = hand.jacobian(q, 0)
        w = u.pad_link_wrench()[0, i].numpy().astype(np.float64)
        names = u.agent.controller.config.joint_names
        flex = [u.action_joint_index[names.index(f"joint_{j}.0")] for j in (1, 2, 3)]
        drive = (kp * (target - q))[flex]
        pad = (J[:3].T @ w[:3] + J[3:].T @ w[3:])[flex]
        assert np.all(drive > 0.05), drive  # the drives push on
        np.testing.assert_allclose(drive, -pad, atol=0.02 * np.abs(drive).max())
        assert np.abs(art.qvel[flex]).max() < 1e-2  # at rest
        # no rigid contact takes a share: the core did not reach the cube
        assert not any(np.any([np.linalg.norm(p.impulse) for p in c.points])
                       for c in u.scene.sub_scenes[0].get_contacts()
                       if "cube" in c.bodies[0].entity.name + c.bodies[1].entity.name)
        # the last MPM step's reaction on the index link is the cube's, reversed
        F_cube = u.object_wrench("cube")[0, :3].numpy()
        np.testing.assert_allclose(w[:3], -F_cube, atol=1e-3 * np.linalg.norm(F_cube))
        # what acts during the next SAPIEN step is part of the env state, for exact replay
        state = u.get_state_dict()
        contacts = state["task"]["pad_contacts"].clone()
        assert contacts.shape == (1, len(u.pad_links) * 2 * 7) and torch.count_nonzero(contacts) > 0
        u._contacts[:] = 0.0
        u.set_state_dict(state)
        # (to float32, what SAPIEN is given: ManiSkill's set_state_dict passes leaves as float32)
        np.testing.assert_array_equal(u._contacts.reshape(1, -1).astype(np.float32),
                                      contacts.numpy().astype(np.float32))
    finally:
        env.close()
    assert all(np.isfinite(forces)) and min(forces) >= 0.0
    assert forces[-1] > 1.0 and abs(forces[-1] - forces[-2]) < 0.01 * forces[-1]  # settled (measured 5.62 N)

    forces_off, env = _press(reaction=False)
    env.close()
    # a kinematic finger goes all the way to its targets and crushes the pad (measured 10.7 N)
    assert forces_off[-1] > 1.5 * forces[-1]

    # the explicit coupling at 2000 Hz runs and pushes the finger back too
    explicit, env = _press(reaction="explicit", steps=2, sim_freq=PAD_REACTION_MIN_FREQ)
    env.close()
    assert all(np.isfinite(explicit)) and min(explicit) >= 0.0 and 0.5 < explicit[-1] < forces_off[-1]


def test_jacobian_of_a_pad_link_is_sapiens_kinematics():
    """JointContact.jacobian (pinocchio, link frame, rotated to the world) against central
    differences of SAPIEN's own link poses: the frame the pad's wrench is mapped through."""
    env = gym.make("GaussTac-Touch-v1", obs_mode="state_dict", sim_backend="physx_cpu", mpm_dx=2e-3)
    try:
        env.reset(seed=0)
        robot = env.unwrapped.agent.robot
        art = robot._objs[0]
        link = robot.links_map[env.unwrapped.pad_links[1]]._objs[0]
        hand = JointContact(art, [link])
        q = art.qpos.astype(np.float64) + 0.1
        art.set_qpos(q.astype(np.float32))
        hand.model.compute_full_jacobian(q)
        J = hand.jacobian(q, 0)

        def pose(qq):
            art.set_qpos(qq.astype(np.float32))
            T = link.entity_pose.to_transformation_matrix().astype(np.float64)
            return T[:3, 3], T[:3, :3]

        numeric, h = np.zeros_like(J), 1e-3
        for k in range(len(q)):
            (p1, R1), (p0, R0) = pose(q + h * np.eye(len(q))[k]), pose(q - h * np.eye(len(q))[k])
            W = (R1 - R0) / (2 * h) @ R0.T
            numeric[:, k] = np.concatenate([(p1 - p0) / (2 * h), [W[2, 1], W[0, 2], W[1, 0]]])
    finally:
        env.close()
    assert np.abs(J).max() > 0.05
    np.testing.assert_allclose(J, numeric, atol=1e-3)


def test_hand_closed_hard_on_a_cube_holds_at_100_hz_with_the_reaction():
    """bench close's case at ManiSkill's rate: every joint driven to close (action +1) on
    PressCube's fixed cube. The explicit coupling flings the index finger at 115 m/s in the
    first step here; folded into the drives, the reaction keeps every pad link slower than
    the closing."""
    env = gym.make("GaussTac-PressCube-v1", sim_backend="physx_cpu", obs_mode="state_dict", mpm_dx=2e-3,
                   pad_reaction=True)
    try:
        env.reset(seed=0)
        u = env.unwrapped
        links = [u.agent.robot.links_map[n] for n in u.pad_links]
        action = np.ones(env.action_space.shape, np.float32)
        speeds, forces = [], []
        for _ in range(10):
            env.step(action)
            speeds.append(max(float(np.linalg.norm(k.get_linear_velocity()[0].numpy())) for k in links))
            forces.append([u.pad_force(p).item() for p in u.pad_names])
    finally:
        env.close()
    forces = np.array(forces)
    assert np.all(np.isfinite(forces)) and forces.min() >= 0.0
    assert forces.max() > 1.0  # the fingers did press the cube (measured peak 13 N)
    assert max(speeds) < 0.5, speeds  # measured 0.24 m/s: the fingers' closing speed


def test_explicit_pad_reaction_below_its_stable_rate_warns():
    with pytest.warns(UserWarning, match="pad_reaction='explicit' at sim_freq=100 Hz"):
        gym.make("GaussTac-Touch-v1", obs_mode="state_dict", sim_backend="physx_cpu", mpm_dx=2e-3,
                 pad_reaction="explicit").close()


def test_implicit_pad_reaction_refuses_tgs():
    with pytest.raises(ConfigError, match="PGS"):
        gym.make("GaussTac-Touch-v1", obs_mode="state_dict", sim_backend="physx_cpu", mpm_dx=2e-3,
                 pad_reaction=True, sim_config=dict(scene_config=dict(enable_tgs=True)))
    with pytest.raises(ConfigError, match="pad_reaction='yes'"):
        gym.make("GaussTac-Touch-v1", obs_mode="state_dict", sim_backend="physx_cpu", pad_reaction="yes")


def test_contact_springs_push_a_free_two_way_cube():
    """With a free, two-way coupled cube the pad's push reaches the cube through a contact
    spring (and the finger through its drives): it slides away and comes to rest."""
    env = gym.make("GaussTac-Touch-v1", obs_mode="state_dict", sim_backend="physx_cpu", mpm_dx=2e-3, cube_gap=1e-3,
                   free_cube=True, two_way=True, pad_reaction=True)
    try:
        env.reset(seed=0)
        u = env.unwrapped
        p0 = u.cube.pose.p[0].numpy().copy()
        action = np.zeros(env.action_space.shape, np.float32)
        names = u.agent.controller.config.joint_names
        action[[names.index(f"joint_{j}.0") for j in (1, 2, 3)]] = 0.3
        for _ in range(6):
            env.step(action)
        moved = np.linalg.norm(u.cube.pose.p[0].numpy() - p0)
        speed = np.linalg.norm(u.cube.linear_velocity[0].numpy())
    finally:
        env.close()
    assert 1e-3 < moved < 2e-2 and speed < 0.01, (moved, speed)
