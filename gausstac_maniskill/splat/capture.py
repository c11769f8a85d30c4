"""Captured 3D Gaussian Splatting scenes and objects: placing them, and loading them with checks.

A capture (a scene trained with gsplat, nerfstudio or the INRIA code and exported as an
INRIA ``.ply``, any SH degree 0..3) lives in its reconstruction's own frame: arbitrary
scale, orientation and origin. A :class:`Similarity` ``x_world = s R(q) x + t`` places it
(:func:`transform_gaussians`). :func:`load_capture` reads the file
(:func:`~gausstac_maniskill.splat.gaussians.load_ply`: ``AssetError`` naming the file and
the property), refuses more than ``max_gaussians`` Gaussians, places it, and warns
(:class:`~gausstac_maniskill.errors.AssetWarning`, naming the file, the field and a fix) when
it looks mis-scaled or too large to render quickly on a CPU. Quaternions are (w, x, y, z).
"""
from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..errors import AssetError, AssetWarning, ConfigError
from ..transforms import matrix_to_quat, quat_to_matrix
from .gaussians import GaussianSet, load_ply, quat_multiply
from .sh import rotate_sh

__all__ = [
    "Similarity",
    "transform_gaussians",
    "load_capture",
    "capture_extent",
    "MAX_GAUSSIANS",
    "WARN_GAUSSIANS",
    "MAX_EXTENT",
    "MIN_EXTENT",
]

#: more Gaussians than this in one file is an error (``max_gaussians=None`` lifts it)
MAX_GAUSSIANS = 10_000_000
#: more than this gets a warning: the CPU rasterizer's frame time grows with the count
WARN_GAUSSIANS = 1_000_000
#: a placed capture wider than this [m] (or narrower than MIN_EXTENT) gets a warning
MAX_EXTENT = 100.0
MIN_EXTENT = 1e-3


@dataclass(frozen=True)
class Similarity:
    """A similarity transform ``x -> s R(q) x + t`` (uniform scale, rotation, translation).

    Attributes:
        scale: s > 0, dimensionless (capture units -> metres).
        rotation: unit quaternion (w, x, y, z); any non-zero quaternion is normalised.
        translation: t [3], metres.
    """

    scale: float = 1.0
    rotation: tuple = (1.0, 0.0, 0.0, 0.0)
    translation: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        s = self.scale
        if not isinstance(s, (int, float, np.floating, np.integer)) or not math.isfinite(s) or s <= 0:
            raise ConfigError(f"Similarity.scale={s!r} must be a finite number > 0")
        q = np.asarray(self.rotation, dtype=np.float64).reshape(-1)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-12:
            raise ConfigError(f"Similarity.rotation={self.rotation!r} must be a non-zero quaternion "
                              "(w, x, y, z)")
        t = np.asarray(self.translation, dtype=np.float64).reshape(-1)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise ConfigError(f"Similarity.translation={self.translation!r} must be 3 finite numbers [m]")
        object.__setattr__(self, "scale", float(s))
        object.__setattr__(self, "rotation", tuple(float(v) for v in q / np.linalg.norm(q)))
        object.__setattr__(self, "translation", tuple(float(v) for v in t))

    @classmethod
    def from_matrix(cls, M, name: str = "similarity") -> "Similarity":
        """From a 4x4 matrix ``[[s R, t], [0, 1]]`` (ConfigError naming ``name`` otherwise)."""
        M = np.asarray(M, dtype=np.float64)
        if M.shape != (4, 4) or not np.all(np.isfinite(M)):
            raise ConfigError(f"{name} must be a finite 4x4 matrix [[s R, t], [0, 0, 0, 1]]")
        A = M[:3, :3]
        det = float(np.linalg.det(A))
        if det <= 0 or np.abs(M[3] - [0, 0, 0, 1]).max() > 1e-9:
            raise ConfigError(f"{name}: not a similarity transform (det of the 3x3 block {det:.3g}, "
                              f"last row {M[3].tolist()})")
        s = det ** (1.0 / 3.0)
        R = A / s
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-4:
            raise ConfigError(f"{name}: the 3x3 block is not a uniform scale times a rotation")
        return cls(s, tuple(matrix_to_quat(R)), tuple(M[:3, 3]))

    @classmethod
    def coerce(cls, value, name: str = "pose") -> "Similarity":
        """A :class:`Similarity` from ``None`` (identity), a Similarity, a dict with any of
        ``scale``, ``rotation`` (w, x, y, z), ``translation`` [m], or a 4x4 matrix."""
        if value is None:
            return cls()
        if isinstance(value, cls):
            return value
        if isinstance(value, dict):
            unknown = set(value) - {"scale", "rotation", "translation"}
            if unknown:
                raise ConfigError(f"{name}: unknown key(s) {sorted(unknown)}; use scale, rotation "
                                  "(quaternion w, x, y, z) and translation [m]")
            try:
                return cls(**value)
            except ConfigError as err:
                raise ConfigError(f"{name}: {err}") from None
        return cls.from_matrix(value, name)

    def as_dict(self) -> dict:
        """``{"scale": s, "rotation": [w, x, y, z], "translation": [x, y, z]}`` (JSON-ready;
        :meth:`coerce` reads it back)."""
        return {"scale": self.scale, "rotation": list(self.rotation), "translation": list(self.translation)}

    def rotation_matrix(self) -> np.ndarray:
        """[3, 3] float64 R."""
        return quat_to_matrix(np.asarray(self.rotation))

    def matrix(self) -> np.ndarray:
        """[4, 4] float64 ``[[s R, t], [0, 1]]``."""
        M = np.eye(4)
        M[:3, :3] = self.scale * self.rotation_matrix()
        M[:3, 3] = self.translation
        return M

    def inverse(self) -> "Similarity":
        """``x -> (1/s) Rᵀ (x - t)``."""
        R = self.rotation_matrix()
        w, x, y, z = self.rotation
        return Similarity(1.0 / self.scale, (w, -x, -y, -z),
                          tuple(-(R.T @ np.asarray(self.translation)) / self.scale))

    def apply(self, points) -> np.ndarray:
        """Points [n, 3] -> s R p + t, float64 [n, 3]."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return self.scale * p @ self.rotation_matrix().T + np.asarray(self.translation)


def transform_gaussians(gaussians: GaussianSet, placement: Similarity) -> GaussianSet:
    """Move a set by a similarity ``x -> s R x + t``, each Gaussian as follows:

    =================  ==============================================================
    mean               μ' = s R μ + t                                     (metres)
    rotation           q' = q ⊗ q_g, so Σ' = s² R Σ Rᵀ
    log-scales         log σ' = log σ + log s
    SH coefficients    c' = ``rotate_sh(c, Rᵀ)``: the colour seen along a world
                       direction d' is the capture's colour along Rᵀ d'
    opacity, labels    unchanged
    =================  ==============================================================

    Args:
        gaussians: N Gaussians in the source frame (means [N, 3] in source units).
        placement: source -> target frame.

    Returns:
        The moved set: means [N, 3] m, quats [N, 4], log_scales [N, 3] (+ log s), SH
        [N, K, 3] rotated by R; the same N, SH degree, opacities and labels, float32 on the
        input's device (computed in float64).
    """
    g = gaussians
    R = placement.rotation_matrix()
    f64 = dict(dtype=torch.float64, device=g.device)
    Rt = torch.as_tensor(R, **f64)
    means = placement.scale * g.means.to(torch.float64) @ Rt.T + torch.as_tensor(placement.translation, **f64)
    q = torch.as_tensor(placement.rotation, **f64).expand(len(g), 4)
    quats = torch.nn.functional.normalize(quat_multiply(q, g.quats.to(torch.float64)), dim=-1)
    sh = rotate_sh(g.sh.to(torch.float64), R.T) if g.sh.shape[1] > 1 else g.sh
    return g.replace(means=means.float(), quats=quats.float(),
                     log_scales=g.log_scales + math.log(placement.scale), sh=sh.float())


def capture_extent(means: torch.Tensor) -> float:
    """Largest side [m] of the box holding the central 98 % of the Gaussians on each axis
    (1st to 99th percentile: a few far floaters do not count); the full box below 100."""
    m = means.detach().to(torch.float64).cpu()
    if len(m) == 0:
        return 0.0
    if len(m) < 100:
        return float((m.max(0).values - m.min(0).values).max())
    if len(m) > 200_000:  # percentiles of an evenly strided subsample: close enough, less sorting
        m = m[torch.linspace(0, len(m) - 1, 200_000, dtype=torch.int64)]
    lo, hi = torch.quantile(m, torch.tensor([0.01, 0.99], dtype=torch.float64), dim=0)
    return float((hi - lo).max())


def load_capture(path: str | os.PathLike, placement: Similarity | dict | None = None, *,
                 max_gaussians: int | None = MAX_GAUSSIANS, warn_gaussians: int | None = WARN_GAUSSIANS,
                 device=None) -> GaussianSet:
    """Read a captured 3DGS scene or object (INRIA ``.ply``, SH degree 0..3) and place it.

    Args:
        path: the ``.ply`` (as written by gsplat, nerfstudio's ``ns-export gaussian-splat``
            or the INRIA code's ``point_cloud.ply``).
        placement: capture frame -> target frame (world for a scene, the actor's frame for
            an object): a :class:`Similarity`, a dict (``scale``, ``rotation`` (w, x, y, z),
            ``translation`` [m]) or a 4x4 ``[[s R, t], [0, 1]]``; ``None``: identity.
        max_gaussians: more vertices than this is an ``AssetError`` (``None``: no limit).
        warn_gaussians: more than this gets an :class:`AssetWarning` (``None``: never).
        device: torch device of the result.

    Returns:
        The placed :class:`GaussianSet` (N Gaussians, the file's SH degree; ``link_id`` 0
        and ``group`` -1 unless the file has those properties).

    Raises:
        AssetError: missing, truncated or malformed file, a missing property, NaN/inf, or
            too many Gaussians; the message names the file and the property or count.
        ConfigError: a malformed ``placement``.

    Warns:
        AssetWarning: more than ``warn_gaussians`` Gaussians; a placed extent above
            :data:`MAX_EXTENT` or below :data:`MIN_EXTENT` (with the scale that would make
            it 1 m wide); Gaussians about as large as the scene (``scale_*`` written as
            linear standard deviations instead of their logs); every ``opacity`` within
            [0, 1] (activated opacities written instead of logits).
    """
    path = Path(path)
    placement = Similarity.coerce(placement, "placement")
    g = load_ply(path, device=device, max_gaussians=max_gaussians)
    name = path.name
    if len(g) == 0:
        raise AssetError(f"{name}: element 'vertex' is empty (no Gaussians)")
    if warn_gaussians is not None and len(g) > warn_gaussians:
        warnings.warn(f"{name}: {len(g):,} Gaussians (more than {warn_gaussians:,}); the CPU rasterizer "
                      "projects every one of them each frame, so frames will be slow: prune or "
                      "downsample the capture (e.g. drop low-opacity Gaussians) for tasks",
                      AssetWarning, stacklevel=2)
    if len(g) >= 100 and bool(((g.opacity_logits >= 0) & (g.opacity_logits <= 1)).all()):
        warnings.warn(f"{name}: every vertex property 'opacity' lies in [0, 1]; INRIA files store the "
                      "logit (sigmoid is applied on load), so all these Gaussians are 50-73 % opaque. "
                      "If the exporter wrote activated opacities, write logit(o) instead",
                      AssetWarning, stacklevel=2)
    g = transform_gaussians(g, placement)
    _check_scale(g, name, placement.scale)
    return g


def _check_scale(g: GaussianSet, name: str, scale: float) -> None:
    """Warnings for a placed capture whose size or Gaussian sizes look wrong."""
    extent = capture_extent(g.means)
    if extent > MAX_EXTENT or 0 < extent < MIN_EXTENT:
        hint = scale / extent  # the scale that makes it 1 m across
        warnings.warn(f"{name}: the placed capture spans {extent:.3g} m (98 % of its Gaussians, "
                      f"'x', 'y', 'z' times scale={scale:.4g}); expected {MIN_EXTENT:g}-{MAX_EXTENT:g} m. "
                      f"Is the placement's scale right? scale={hint:.4g} makes it 1 m across",
                      AssetWarning, stacklevel=3)
    if len(g) >= 10 and extent > 0:
        size = float(g.log_scales.max(dim=1).values.median().exp())
        if size > 0.5 * extent:
            warnings.warn(f"{name}: the median Gaussian's largest standard deviation is {size:.3g} m, "
                          f"more than half the capture's extent ({extent:.3g} m): vertex properties "
                          "'scale_0..2' must hold log standard deviations; were linear ones written?",
                          AssetWarning, stacklevel=3)
