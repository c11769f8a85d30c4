"""The two fronts of the one quaternion convention (w, x, y, z) in transforms.py agree:
numpy (on the host) and torch (any device), both batched. What this guards: that
the two formulas stay the same convention; it is not a physics check."""
import numpy as np
import torch
from scipy.spatial.transform import Rotation

import pytest

from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.transforms import (as_pose_matrices, matrix_to_quat, quat_multiply, quat_to_matrix, quat_to_rotmat,
                                           rotmat_to_quat, vec7_to_matrix)


def _rotations(n=64, seed=0):
    R = Rotation.random(n, random_state=seed).as_matrix()
    R[:4] = [np.eye(3), np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])]  # 180°
    return R


def test_numpy_and_torch_agree_with_scipy_and_each_other():
    R = _rotations()
    q_np = matrix_to_quat(R)
    q_t = rotmat_to_quat(torch.as_tensor(R)).numpy()
    xyzw = Rotation.from_matrix(R).as_quat()
    ref = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)
    ref *= np.where(ref[:, :1] < 0, -1.0, 1.0)
    for q in (q_np, q_t):
        assert (q[:, 0] >= 0).all()
        assert np.allclose(np.abs((q * ref).sum(1)), 1.0, atol=1e-12)  # same rotation (sign at w = 0)
    assert np.allclose(quat_to_matrix(q_np), R, atol=1e-12)
    assert np.array_equal(np.stack([matrix_to_quat(M) for M in R]), q_np)  # one at a time = batched
    assert np.allclose(quat_to_rotmat(torch.as_tensor(q_t)).numpy(), R, atol=1e-12)


def test_product_and_raw_pose():
    R = _rotations(8, seed=1)
    q = torch.as_tensor(matrix_to_quat(R))
    ab = quat_multiply(q[:4], q[4:])
    assert np.allclose(quat_to_rotmat(ab).numpy(), R[:4] @ R[4:], atol=1e-12)
    raw = torch.cat([torch.tensor([[0.1, -0.2, 0.3]], dtype=torch.float64).expand(8, 3), q], dim=1)
    T = vec7_to_matrix(raw).numpy()
    assert np.allclose(T[:, :3, :3], R, atol=1e-12) and np.allclose(T[:, :3, 3], [0.1, -0.2, 0.3])
    assert np.allclose(T[:, 3], [0.0, 0.0, 0.0, 1.0])


def test_pose_batches_are_checked_in_one_pass_and_name_the_bad_one():
    T = np.tile(np.eye(4), (2, 3, 1, 1))
    T[..., :3, :3] = _rotations(6, seed=2).reshape(2, 3, 3, 3)
    assert np.array_equal(as_pose_matrices(T), T)
    bad = T.copy()
    bad[1, 2, 0, 3] = np.nan
    with pytest.raises(ConfigError, match=r"poses contains NaN or inf at index \[1, 2\]"):
        as_pose_matrices(bad, "poses")
    bad = T.copy()
    bad[0, 1, :3, :3] *= -1.0  # a reflection
    with pytest.raises(ConfigError, match=r"poses at index \[0, 1\]: the upper-left 3x3 block is not a rotation"):
        as_pose_matrices(bad, "poses")


def test_turn_angle_is_the_rotation_angle_between_two_poses():
    """turn_angle(a, b) is the angle of the rotation Rₐᵀ R_b, batched, in [0, π]."""
    from gausstac_maniskill.transforms import make_pose, rotation_about, turn_angle

    a = make_pose([0.1, 0.0, 0.0], rotation_about([0.0, 1.0, 0.0], 0.3))
    angles = [0.0, 0.2, 1.5, np.pi]
    b = np.stack([a @ make_pose([0.0, 0.5, 0.0], rotation_about([1.0, 1.0, 0.0], t)) for t in angles])
    np.testing.assert_allclose(turn_angle(a[None], b), angles, atol=1e-6)
    assert float(turn_angle(a, a)) == 0.0
