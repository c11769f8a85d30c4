"""Pinhole cameras for the rasterizer, OpenCV convention (camera x right, y down, z forward):
intrinsics from a field of view, a look-at view matrix, and SAPIEN camera poses as
world -> camera extrinsics. Float32 torch tensors; metres, radians, pixels."""

import math

import torch

from ..errors import ConfigError

__all__ = ["intrinsics_from_fov", "look_at", "sapien_pose_to_opencv_extrinsic"]


def intrinsics_from_fov(width: int, height: int, fovy: float, fovx: float | None = None,
                        device=None) -> torch.Tensor:
    """[3, 3] pinhole K for a vertical field of view ``fovy`` (radians).

    ``fovx`` defaults to square pixels (fx = fy). The principal point is the
    image centre (W/2, H/2), as in SAPIEN's cameras.
    """
    fy = 0.5 * height / math.tan(0.5 * fovy)
    fx = fy if fovx is None else 0.5 * width / math.tan(0.5 * fovx)
    return torch.tensor([[fx, 0.0, 0.5 * width], [0.0, fy, 0.5 * height], [0.0, 0.0, 1.0]],
                        dtype=torch.float32, device=device)


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> torch.Tensor:
    """[4, 4] OpenCV world -> camera matrix for a camera at ``eye`` looking at ``target``.

    Camera z points to the target, x right and y down in the image, with
    ``up`` (world) appearing upwards.
    """
    eye, target, up = (torch.as_tensor(v, dtype=torch.float64) for v in (eye, target, up))
    z = target - eye
    z = z / z.norm()
    x = torch.linalg.cross(z, up)
    if x.norm() < 1e-9:
        raise ConfigError("look_at: viewing direction is parallel to up")
    x = x / x.norm()
    y = torch.linalg.cross(z, x)
    R = torch.stack([x, y, z])  # rows: camera axes in world coordinates
    M = torch.eye(4, dtype=torch.float64)
    M[:3, :3] = R
    M[:3, 3] = -R @ eye
    return M.float()


# camera axes (rows) of OpenCV expressed in the other conventions' axes
_CV_FROM_SAPIEN = torch.tensor([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])  # x fwd, y left, z up
_CV_FROM_OPENGL = torch.tensor([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])  # x right, y up, z back


def sapien_pose_to_opencv_extrinsic(pose, convention: str = "sapien") -> torch.Tensor:
    """World -> camera [..., 4, 4] OpenCV extrinsic from a SAPIEN camera pose.

    Args:
        pose: [..., 4, 4] camera -> world transform (array-like or
            ``sapien.Pose``, whose ``to_transformation_matrix()`` is used).
        convention: axes of ``pose``'s camera frame:

            * ``"sapien"`` — the camera entity pose (``camera.entity_pose``,
              ``camera.get_pose()``): x forward, y left, z up;
            * ``"opengl"`` — ``camera.get_model_matrix()``: x right, y up, z backward.

    Returns:
        [..., 4, 4] float32 ``viewmat`` for :func:`rasterize` (x right, y down,
        z forward). Equals SAPIEN's ``camera.get_extrinsic_matrix()`` (3×4) in
        its top three rows.

    The maths: with ``pose = [R | p]`` (camera -> world), the OpenCV axes are
    ``x_cv = -y_s, y_cv = -z_s, z_cv = x_s`` (SAPIEN) or ``x_cv = x_gl,
    y_cv = -y_gl, z_cv = -z_gl`` (OpenGL), i.e. ``R_cv = A`` with rows above;
    extrinsic = ``[A Rᵀ | -A Rᵀ p]``.
    """
    if hasattr(pose, "to_transformation_matrix"):
        pose = pose.to_transformation_matrix()
    pose = torch.as_tensor(pose, dtype=torch.float64)
    if pose.shape[-2:] != (4, 4):
        raise ConfigError(f"pose has shape {list(pose.shape)}, expected [..., 4, 4]")
    if convention == "sapien":
        A = _CV_FROM_SAPIEN
    elif convention == "opengl":
        A = _CV_FROM_OPENGL
    else:
        raise ConfigError(f"convention={convention!r} must be 'sapien' or 'opengl'")
    A = A.to(torch.float64)
    R, p = pose[..., :3, :3], pose[..., :3, 3:]
    Rw = A @ R.transpose(-1, -2)
    out = torch.zeros(pose.shape, dtype=torch.float64)
    out[..., :3, :3] = Rw
    out[..., :3, 3:] = -Rw @ p
    out[..., 3, 3] = 1.0
    return out.float()
