"""3D Gaussian Splatting: Gaussian sets and their .ply files, a Taichi rasterizer
(CPU and CUDA), deformation of Gaussians by rigid links and MPM particles, and their
shading with a scene's lights."""
from .gaussians import (SH_C0, GaussianSet, covariance_from_scale_rotation, load_ply,
                        num_sh_coeffs, quat_multiply, quat_to_rotmat, rgb_to_sh_dc,
                        rotmat_to_quat, save_ply, sh_dc_to_rgb)
from .deform import (FramedGaussians, PosedGaussians, SoftBinding, particle_frames,
                     polar_rotation, pose_gaussians, rigid_frames, rigid_transform, soft_deform)
from .capture import Similarity, load_capture, transform_gaussians
from .lighting import MANISKILL_DEFAULT, Lighting, surface_normals
from .cameras import intrinsics_from_fov, look_at, sapien_pose_to_opencv_extrinsic
from .rasterizer import RenderOutput, rasterize, render

__all__ = [
    "GaussianSet", "load_ply", "save_ply", "SH_C0", "rgb_to_sh_dc", "sh_dc_to_rgb",
    "num_sh_coeffs", "quat_to_rotmat", "quat_multiply", "rotmat_to_quat",
    "covariance_from_scale_rotation",
    "RenderOutput", "rasterize", "render", "intrinsics_from_fov", "look_at",
    "sapien_pose_to_opencv_extrinsic",
    "rigid_transform", "polar_rotation", "SoftBinding", "soft_deform", "PosedGaussians",
    "pose_gaussians", "FramedGaussians", "rigid_frames", "particle_frames",
    "Similarity", "load_capture", "transform_gaussians",
    "Lighting", "MANISKILL_DEFAULT", "surface_normals",
]
