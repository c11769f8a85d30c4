"""Rigid transforms in numpy: 4x4 matrices <-> (position, quaternion wxyz), applied to points."""
from __future__ import annotations

import numpy as np

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
