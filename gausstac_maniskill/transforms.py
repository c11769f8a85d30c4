"""Rigid transforms: 4x4 matrices <-> (position, quaternion wxyz), applied to points.

The quaternion conversions live here only: torch (:func:`quat_to_rotmat`,
:func:`rotmat_to_quat`, :func:`quat_multiply`, :func:`vec7_to_matrix`) and numpy
(:func:`quat_to_matrix`, :func:`matrix_to_quat`; the same formulas, tested against each
other in ``tests/test_transforms.py``).
"""
from __future__ import annotations

import numpy as np
import torch

from .errors import ConfigError


def as_pose_matrix(pose, name: str = "pose") -> np.ndarray:
    """Validate and return a 4x4 float64 rigid transform (rotation checked orthonormal)."""
    T = np.asarray(pose, dtype=np.float64)
    if T.shape != (4, 4):
        raise ConfigError(f"{name} must be a 4x4 matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ConfigError(f"{name} contains NaN or inf")
    R = T[:3, :3]
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0:
        raise ConfigError(f"{name}: the upper-left 3x3 block is not a rotation matrix")
    return T


# --------------------------------------------------------------------------- quaternions
# The project's quaternion convention (w, x, y, z), Hamilton product, in one module: torch
# (batched, on any device and float dtype) and numpy (float64, for single poses on the
# host: calling torch there costs 160-290 µs per matrix against 10-26 µs). Inside Taichi
# kernels: :func:`gausstac_maniskill.mpm.kinematics.quat_to_mat`.
def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    """Quaternions (w, x, y, z) [..., 4] -> rotation matrices [..., 3, 3]; normalised first,
    so any non-zero quaternion is accepted."""
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    rows = (
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    )
    return torch.stack(rows, dim=-1).reshape(q.shape[:-1] + (3, 3))


def rotmat_to_quat(R: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [..., 3, 3] -> unit quaternions (w, x, y, z) [..., 4], w >= 0.

    Shepperd's method: the largest of (trace, R00, R11, R22) picks the stable formula.
    """
    m = R.reshape(-1, 3, 3)
    t = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    choice = torch.stack([t, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], dim=-1).argmax(dim=-1)

    def root(v):
        return torch.sqrt(torch.clamp(1 + v, min=1e-12)) * 2

    s = root(t)
    q0 = torch.stack([0.25 * s, (m[:, 2, 1] - m[:, 1, 2]) / s,
                      (m[:, 0, 2] - m[:, 2, 0]) / s, (m[:, 1, 0] - m[:, 0, 1]) / s], -1)
    s = root(m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2])
    q1 = torch.stack([(m[:, 2, 1] - m[:, 1, 2]) / s, 0.25 * s,
                      (m[:, 0, 1] + m[:, 1, 0]) / s, (m[:, 0, 2] + m[:, 2, 0]) / s], -1)
    s = root(m[:, 1, 1] - m[:, 0, 0] - m[:, 2, 2])
    q2 = torch.stack([(m[:, 0, 2] - m[:, 2, 0]) / s, (m[:, 0, 1] + m[:, 1, 0]) / s,
                      0.25 * s, (m[:, 1, 2] + m[:, 2, 1]) / s], -1)
    s = root(m[:, 2, 2] - m[:, 0, 0] - m[:, 1, 1])
    q3 = torch.stack([(m[:, 1, 0] - m[:, 0, 1]) / s, (m[:, 0, 2] + m[:, 2, 0]) / s,
                      (m[:, 1, 2] + m[:, 2, 1]) / s, 0.25 * s], -1)
    q = torch.stack([q0, q1, q2, q3], dim=1)[torch.arange(m.shape[0], device=R.device), choice]
    q = q * torch.where(q[:, :1] < 0, -1.0, 1.0).to(q.dtype)
    q = q / q.norm(dim=-1, keepdim=True)
    return q.reshape(R.shape[:-2] + (4,))


def quat_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product a ⊗ b of quaternions (w, x, y, z) [..., 4] (broadcasting):
    ``R(a ⊗ b) = R(a) R(b)``, rotate by b first, then by a."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack((
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ), dim=-1)


def vec7_to_matrix(raw_pose: torch.Tensor) -> torch.Tensor:
    """``[..., 7]`` poses (px, py, pz, qw, qx, qy, qz), SAPIEN's ``raw_pose`` layout ->
    ``[..., 4, 4]`` transforms, on the poses' device and in their dtype."""
    T = torch.zeros(raw_pose.shape[:-1] + (4, 4), dtype=raw_pose.dtype, device=raw_pose.device)
    T[..., :3, :3] = quat_to_rotmat(raw_pose[..., 3:7])
    T[..., :3, 3] = raw_pose[..., :3]
    T[..., 3, 3] = 1
    return T


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrix [...,3,3] -> unit quaternion [...,4] (w, x, y, z), w >= 0."""
    R = np.asarray(R, dtype=np.float64)
    flat = R.reshape(-1, 3, 3)
    out = np.empty((flat.shape[0], 4))
    for n, M in enumerate(flat):
        t = np.trace(M)
        if t > 0:
            s = 2.0 * np.sqrt(t + 1.0)
            q = [0.25 * s, (M[2, 1] - M[1, 2]) / s, (M[0, 2] - M[2, 0]) / s, (M[1, 0] - M[0, 1]) / s]
        else:
            i = int(np.argmax(np.diag(M)))
            j, k = (i + 1) % 3, (i + 2) % 3
            s = 2.0 * np.sqrt(max(1.0 + M[i, i] - M[j, j] - M[k, k], 1e-300))
            q = np.empty(4)
            q[0] = (M[k, j] - M[j, k]) / s
            q[1 + i] = 0.25 * s
            q[1 + j] = (M[j, i] + M[i, j]) / s
            q[1 + k] = (M[k, i] + M[i, k]) / s
        q = np.asarray(q, dtype=np.float64)
        q /= np.linalg.norm(q)
        out[n] = q if q[0] >= 0 else -q
    return out.reshape(R.shape[:-2] + (4,))


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Unit quaternion [...,4] (w, x, y, z) -> rotation matrix [...,3,3]."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    R = np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1)
    return R.reshape(q.shape[:-1] + (3, 3))


def pose_to_vec7(T: np.ndarray) -> np.ndarray:
    """4x4 transform -> [px, py, pz, qw, qx, qy, qz]."""
    return np.concatenate([T[:3, 3], matrix_to_quat(T[:3, :3])])


def make_pose(position=(0.0, 0.0, 0.0), rotation=None) -> np.ndarray:
    """Build a 4x4 transform from a position and an optional 3x3 rotation."""
    T = np.eye(4)
    T[:3, 3] = position
    if rotation is not None:
        T[:3, :3] = rotation
    return T


def rotation_about(axis, angle: float) -> np.ndarray:
    """3x3 rotation of ``angle`` radians about ``axis`` (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points [n, 3] (metres) moved by the 4x4 rigid transform ``T``: ``R p + t`` per row."""
    return points @ T[:3, :3].T + T[:3, 3]
