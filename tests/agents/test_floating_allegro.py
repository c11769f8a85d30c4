"""The floating Allegro agent: its root joints move the hand as the agent's pose helpers say
(checked against SAPIEN's kinematics), and its pinch point is reachable by the thumb and
index pads with opposed normals."""
import gymnasium as gym
import numpy as np
import pytest
import torch

import gausstac_maniskill  # noqa: F401  (registers the agents and tasks)
from gausstac_maniskill.agents.allegro import (ALLEGRO_PINCH_AXIS, ALLEGRO_PINCH_CENTRE,
                                               FloatingAllegroHandRightGaussTac, pinch_down_rotation)
from gausstac_maniskill.experts import TipIK
from gausstac_maniskill.transforms import vec7_to_matrix
from gausstac_maniskill.urdf import FLOATING_JOINTS, parse_urdf

pytestmark = pytest.mark.sapien


def test_floating_urdf_hangs_the_hand_from_six_root_joints():
    model = parse_urdf(FloatingAllegroHandRightGaussTac.urdf_path)
    assert set(FLOATING_JOINTS) <= set(model.joint_names) and len(model.joint_names) == 22
    root = [0.1, -0.2, 0.3, 0.4, -0.5, 0.6]
    # the URDF's own forward kinematics agrees with the agent's pose helper
    fk = model.forward_kinematics(dict(zip(FLOATING_JOINTS, root)))
    np.testing.assert_allclose(fk["base_link"], FloatingAllegroHandRightGaussTac.base_pose(root), atol=1e-12)


def test_root_joints_in_sapien_put_the_base_where_base_pose_says():
    env = gym.make("GaussTac-GraspLiftCube-v1", obs_mode="state_dict", mpm_dx=2e-3, sim_backend="physx_cpu")
    try:
        env.reset(seed=0)
        base = env.unwrapped
        from scipy.spatial.transform import Rotation

        rng = np.random.default_rng(0)
        for R in Rotation.random(3, random_state=1).as_matrix():
            T = np.eye(4)
            T[:3, :3] = R
            T[:3, 3] = rng.uniform(-0.2, 0.2, 3)
            q = np.zeros(22)
            q[:6] = FloatingAllegroHandRightGaussTac.root_qpos(T)
            base.agent.robot.set_qpos(base.action_order_to_qpos(torch.as_tensor(q[None], dtype=torch.float32)))
            P = vec7_to_matrix(base.agent.robot.links_map["base_link"].pose.raw_pose)[0].double().numpy()
            np.testing.assert_allclose(P, T, atol=2e-5)
    finally:
        env.close()


def test_pinch_is_reached_with_opposed_pad_normals():
    env = gym.make("GaussTac-GraspLiftCube-v1", obs_mode="state_dict", mpm_dx=2e-3, sim_backend="physx_cpu")
    try:
        env.reset(seed=0)
        base = env.unwrapped
        c, u = np.asarray(ALLEGRO_PINCH_CENTRE), np.asarray(ALLEGRO_PINCH_AXIS)
        q = base.qpos_in_action_order()[0].double().numpy()
        for pad, joints, sign in (("thumb", (12, 13, 14, 15), -1.0), ("index", (0, 1, 2, 3), 1.0)):
            ik = TipIK(base, pad, [f"joint_{j}.0" for j in joints])
            target = c + sign * 0.02 * u  # the faces of a 20 mm (half size) cube at the pinch point
            F = ik.frame(ik.solve(q, target, normal=-sign * u))
            assert np.linalg.norm(F[:3, 3] - target) < 3e-3, (pad, F[:3, 3] - target)
            assert np.degrees(np.arccos(np.clip(F[:3, 2] @ (-sign * u), -1, 1))) < 10.0, pad
        R = pinch_down_rotation()
        np.testing.assert_allclose(R @ u, [0, 1, 0], atol=1e-12)  # pinch axis along world +y
        down = R @ c
        # the pinch point hangs below the base (off it only along the pinch axis)
        np.testing.assert_allclose(down[:2], [0.0, c @ u], atol=1e-12)
        assert down[2] < -0.1
    finally:
        env.close()
