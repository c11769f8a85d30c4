"""Real spherical harmonics (degree 0..3) in the 3D Gaussian Splatting convention.

A Gaussian's colour seen along unit direction d is ``Σ_k c_k Y_k(d) + 0.5``
(clamped at 0) with K = (degree + 1)² coefficients c_k per colour channel; the
basis Y_k, its constants and signs are those of the INRIA code (and of the
rasterizer's kernel, which uses the constants below).
"""
from __future__ import annotations

import numpy as np
import torch

from ..errors import ConfigError

__all__ = [
    "SH_C0",
    "SH_C1",
    "SH_C2",
    "SH_C3",
    "num_sh_coeffs",
    "sh_degree_from_coeffs",
    "rgb_to_sh_dc",
    "sh_dc_to_rgb",
    "sh_basis",
    "rotate_sh",
]

#: Real spherical harmonic Y_0^0 = 1 / (2 sqrt(pi)).
SH_C0 = 0.28209479177387814
#: Degree-1 constant sqrt(3 / (4 pi)).
SH_C1 = 0.4886025119029199
#: Degree-2 constants, coefficients 4..8.
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
         -1.0925484305920792, 0.5462742152960396)
#: Degree-3 constants, coefficients 9..15.
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def num_sh_coeffs(degree: int) -> int:
    """Number K of SH coefficients per colour channel for ``degree`` (0..3)."""
    if degree not in (0, 1, 2, 3):
        raise ConfigError(f"SH degree {degree!r} must be 0, 1, 2 or 3")
    return (degree + 1) ** 2


def sh_degree_from_coeffs(k: int) -> int:
    """Inverse of :func:`num_sh_coeffs`; ConfigError unless K is 1, 4, 9 or 16."""
    for d in range(4):
        if (d + 1) ** 2 == k:
            return d
    raise ConfigError(f"{k} SH coefficients per channel is not (degree+1)^2 for degree 0..3")


def rgb_to_sh_dc(rgb: torch.Tensor) -> torch.Tensor:
    """Colour in [0, 1] -> DC SH coefficient, so that ``SH_C0 * dc + 0.5 == rgb``."""
    return (rgb - 0.5) / SH_C0


def sh_dc_to_rgb(dc: torch.Tensor) -> torch.Tensor:
    """DC SH coefficient -> view-independent colour (before the clamp at 0)."""
    return dc * SH_C0 + 0.5


def sh_basis(d: np.ndarray, degree: int) -> np.ndarray:
    """Basis values Y_k at unit directions.

    Args:
        d: [m, 3] unit directions.
        degree: SH degree 0..3.

    Returns:
        [m, K] float array, K = (degree + 1)², in coefficient order.
    """
    x, y, z = np.asarray(d, dtype=np.float64).T
    b = [np.full_like(x, SH_C0)]
    if degree >= 1:
        b += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        b += [SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2 * zz - xx - yy),
              SH_C2[3] * x * z, SH_C2[4] * (xx - yy)]
    if degree >= 3:
        b += [SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * x * y * z,
              SH_C3[2] * y * (4 * zz - xx - yy), SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
              SH_C3[4] * x * (4 * zz - xx - yy), SH_C3[5] * z * (xx - yy),
              SH_C3[6] * x * (xx - 3 * yy)]
    return np.stack(b, axis=-1)


def rotate_sh(sh: torch.Tensor, R: np.ndarray) -> torch.Tensor:
    """SH coefficients re-expressed in a rotated frame.

    Args:
        sh: [n, K, 3] coefficients (K = 1, 4, 9 or 16).
        R: [3, 3] rotation mapping new-frame directions to old-frame ones
            (d_old = R d_new).

    Returns:
        [n, K, 3] coefficients c' (same dtype) with Σ c'_k Y_k(d) = Σ c_k Y_k(R d)
        for every d. Each band is closed under rotation, so the K×K matrix is
        solved exactly by least squares on random directions.
    """
    degree = sh_degree_from_coeffs(sh.shape[1])
    if degree == 0:
        return sh.clone()
    d = np.random.default_rng(0).normal(size=(64, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    B, BR = sh_basis(d, degree), sh_basis(d @ np.asarray(R).T, degree)
    M = np.linalg.lstsq(B, BR, rcond=None)[0]  # B M = BR  ->  c' = M c
    return torch.einsum("kj,njc->nkc", torch.as_tensor(M, dtype=sh.dtype), sh)
