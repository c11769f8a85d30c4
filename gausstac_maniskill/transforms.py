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
    return as_pose_matrices(T[None], name)[0]


def as_pose_matrices(poses, name: str = "poses") -> np.ndarray:
    """Validate and return [..., 4, 4] float64 rigid transforms in one pass (every rotation
    checked orthonormal); the error names the first bad pose's index."""
    T = np.asarray(poses, dtype=np.float64)
    if T.ndim < 2 or T.shape[-2:] != (4, 4):
        raise ConfigError(f"{name} must have shape [..., 4, 4], got {list(T.shape)}")
    flat = T.reshape(-1, 4, 4)

    def where(i: int) -> str:
        return "" if T.ndim == 2 else f" at index {[int(k) for k in np.unravel_index(i, T.shape[:-2])]}"

    bad = ~np.isfinite(flat).all(axis=(1, 2))
    if bad.any():
        raise ConfigError(f"{name} contains NaN or inf{where(int(np.argmax(bad)))}")
    R = flat[:, :3, :3]
    err = np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
    bad = (err > 1e-4) | (np.linalg.det(R) < 0)
    if bad.any():
        raise ConfigError(f"{name}{where(int(np.argmax(bad)))}: the upper-left 3x3 block is not a rotation matrix")
    return T


# --------------------------------------------------------------------------- quaternions
# The project's quaternion convention (w, x, y, z), Hamilton product, in one module: torch
# (batched, on any device and float dtype) and numpy (batched, float64, on the host: much
# cheaper than torch for a single pose). Inside Taichi
# kernels: :func:`gausstac_maniskill.geometry.kinematics.quat_to_mat`.
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
    """Rotation matrix [...,3,3] -> unit quaternion [...,4] (w, x, y, z), w >= 0 (all at once:
    the formula of the trace when it is positive, else of the largest diagonal entry)."""
    R = np.asarray(R, dtype=np.float64)
    M = R.reshape(-1, 3, 3)
    n = np.arange(M.shape[0])
    t = np.trace(M, axis1=1, axis2=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = 2.0 * np.sqrt(t + 1.0)
        by_trace = np.stack([0.25 * s, (M[:, 2, 1] - M[:, 1, 2]) / s, (M[:, 0, 2] - M[:, 2, 0]) / s,
                             (M[:, 1, 0] - M[:, 0, 1]) / s], -1)
        i = np.argmax(np.diagonal(M, axis1=1, axis2=2), axis=1)
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(np.maximum(1.0 + M[n, i, i] - M[n, j, j] - M[n, k, k], 1e-300))
        by_diag = np.empty_like(by_trace)
        by_diag[:, 0] = (M[n, k, j] - M[n, j, k]) / s
        by_diag[n, 1 + i] = 0.25 * s
        by_diag[n, 1 + j] = (M[n, j, i] + M[n, i, j]) / s
        by_diag[n, 1 + k] = (M[n, k, i] + M[n, i, k]) / s
    q = np.where((t > 0)[:, None], by_trace, by_diag)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.where(q[:, :1] >= 0, 1.0, -1.0)
    return q.reshape(R.shape[:-2] + (4,))


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


def turn_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """[...] angle [rad] of the rotation that turns pose a's orientation into pose b's
    ([..., 4, 4] or [..., 3, 3] each): arccos((trace(Rₐᵀ R_b) - 1) / 2)."""
    cos = (np.einsum("...ji,...ji->...", a[..., :3, :3], b[..., :3, :3]) - 1.0) / 2.0  # trace(aᵀ b)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points [n, 3] (metres) moved by the 4x4 rigid transform ``T``: ``R p + t`` per row."""
    return points @ T[:3, :3].T + T[:3, 3]
