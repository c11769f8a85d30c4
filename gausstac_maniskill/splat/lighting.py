"""Scene lighting for Gaussians: the diffuse part of SAPIEN's shading, per Gaussian.

A lit Gaussian, one with a normal (the flat ones: :func:`surface_normals`), is shaded like a
mesh point in SAPIEN's rasterizing shaders (``minimal``, ManiSkill's camera default, and
``default``): its SH colour is the linear albedo a, its shortest axis moved by its frame the
normal n, lit by an ambient colour A and directional lights Eᵢ travelling along dᵢ::

    c_lin = A·a + Σᵢ Eᵢ · a · max(0, n·lᵢ) / π,  lᵢ = -dᵢ / |dᵢ|,  pixel = clamp(c_lin^(1/2.2), 0, 1)

Normals are two-sided (turned to face the camera) and move with cof(M) = det(M)·M⁻ᵀ under a
frame ``x -> M x + t``. A Gaussian with the zero normal (a captured scene's, lighting baked
in) keeps its colour. Not modelled: SAPIEN's GGX specular term (Gaussians carry no roughness
or metalness), shadows, point and spot lights, the environment map
(:meth:`Lighting.from_sapien` warns). World frame; colours RGB, linear, >= 0; directions as
SAPIEN's ``add_directional_light`` (the direction the light travels, any length > 0).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import ConfigError
from .gaussians import quat_to_rotmat

__all__ = ["Lighting", "MANISKILL_DEFAULT", "FLATNESS", "surface_normals"]

#: a Gaussian is flat (gets a normal) when its shortest axis is at most this fraction of
#: the middle one (surface Gaussians built by :mod:`.surface` have 1/18)
FLATNESS = 0.5


@dataclass(frozen=True)
class Lighting:
    """Ambient light plus directional lights, as SAPIEN's scene holds them.

    Attributes:
        ambient: (3,) RGB ambient colour A (``scene.set_ambient_light``), >= 0.
        directions: (L, 3) world directions the lights travel (``add_directional_light``'s
            first argument; normalised here), L >= 0.
        colors: (L, 3) RGB colours Eᵢ of the lights, >= 0.
        gamma: the shaded linear colour is written as c^(1/gamma) (SAPIEN: 2.2; 1: linear).
    """

    ambient: tuple = (0.0, 0.0, 0.0)
    directions: tuple = ()
    colors: tuple = ()
    gamma: float = 2.2

    def __post_init__(self) -> None:
        amb = np.asarray(self.ambient, dtype=np.float64).reshape(-1)
        d = np.asarray(self.directions, dtype=np.float64).reshape(-1, 3)
        e = np.asarray(self.colors, dtype=np.float64).reshape(-1, 3)
        if amb.shape != (3,) or not np.all(np.isfinite(amb)) or amb.min() < 0:
            raise ConfigError(f"Lighting.ambient={self.ambient!r} must be an RGB triple >= 0")
        if len(d) != len(e):
            raise ConfigError(f"Lighting: {len(d)} directions but {len(e)} colours")
        if not (np.all(np.isfinite(d)) and np.all(np.isfinite(e))) or (len(e) and e.min() < 0):
            raise ConfigError("Lighting: light directions must be finite and colours finite and >= 0")
        norm = np.linalg.norm(d, axis=1)
        if np.any(norm < 1e-12):
            raise ConfigError("Lighting: a light direction is the zero vector")
        if not (np.isfinite(self.gamma) and self.gamma > 0):
            raise ConfigError(f"Lighting.gamma={self.gamma!r} must be > 0")
        object.__setattr__(self, "ambient", tuple(float(v) for v in amb))
        object.__setattr__(self, "directions", tuple(tuple(float(v) for v in r) for r in d / norm[:, None]))
        object.__setattr__(self, "colors", tuple(tuple(float(v) for v in r) for r in e))
        object.__setattr__(self, "gamma", float(self.gamma))

    @property
    def is_grey(self) -> bool:
        """Whether the ambient light and every light colour have equal R, G and B (then the
        light falling on a surface is one number, and the rasterizer shades with one power
        per Gaussian instead of three)."""
        return all(c[0] == c[1] == c[2] for c in (self.ambient, *self.colors))

    @classmethod
    def from_sapien(cls, scene) -> "Lighting":
        """The ambient and enabled directional lights of a ``sapien.Scene`` (a ManiSkill
        scene's ``sub_scenes[i]``). Warns about what it leaves out: point and spot lights,
        shadows and an environment map."""
        rs = scene.render_system
        directions, colors, skipped = [], [], []
        for light in rs.lights:
            if not light.is_enabled:
                continue
            kind = type(light).__name__
            if kind == "RenderDirectionalLightComponent":
                # a directional light travels along its entity's x axis
                directions.append(light.global_pose.to_transformation_matrix()[:3, 0])
                colors.append(np.asarray(light.color, dtype=np.float64)[:3])
                if light.shadow:
                    skipped.append(f"{kind} shadow")
            else:
                skipped.append(kind)
        if rs.cubemap is not None:
            skipped.append("environment map")
        if skipped:
            warnings.warn(f"Lighting.from_sapien: Gaussians are shaded with the ambient and directional "
                          f"lights only; not modelled: {', '.join(sorted(set(skipped)))}", stacklevel=2)
        return cls(tuple(np.asarray(scene.ambient_light, dtype=np.float64)[:3]),
                   tuple(map(tuple, directions)), tuple(map(tuple, colors)))

    def kernel_array(self, device=None) -> torch.Tensor:
        """[1 + L, 6] float32 as the rasterizer's projection kernel reads it: row 0 =
        (A, 1/gamma, 0, 0); row 1 + i = (lᵢ = -dᵢ toward the light, Eᵢ / π)."""
        key = str(device)
        arrays = self.__dict__.setdefault("_arrays", {})  # built once per device (the Lighting is frozen)
        if key not in arrays:
            rows = [list(self.ambient) + [1.0 / self.gamma, 0.0, 0.0]]
            for d, e in zip(self.directions, self.colors):
                rows.append([-d[0], -d[1], -d[2]] + [v / math.pi for v in e])
            arrays[key] = torch.tensor(rows, dtype=torch.float32, device=device)
        return arrays[key]


#: ManiSkill's default ``_load_lighting`` (used by every GaussTac task): ambient 0.3,
#: white lights travelling along (1, 1, -1) and (0, 0, -1), no shadows.
MANISKILL_DEFAULT = Lighting((0.3, 0.3, 0.3), ((1.0, 1.0, -1.0), (0.0, 0.0, -1.0)),
                             ((1.0, 1.0, 1.0), (1.0, 1.0, 1.0)))


def surface_normals(quats: torch.Tensor, scales: torch.Tensor, flatness: float = FLATNESS) -> torch.Tensor:
    """[N, 3] unit normals of flat Gaussians (their shortest axis; sign as the axis),
    the zero vector for Gaussians that are not flat (shortest σ > ``flatness`` × middle σ).

    Args:
        quats: [N, 4] rotations (w, x, y, z).
        scales: [N, 3] standard deviations (not log), any unit.
    """
    if quats.shape[0] == 0:
        return torch.zeros(0, 3, dtype=torch.float32, device=quats.device)
    R = quat_to_rotmat(quats.to(torch.float32))
    s, order = torch.sort(scales.to(torch.float32), dim=-1)
    axis = R.gather(-1, order[:, None, :1].expand(-1, 3, 1)).squeeze(-1)  # column of the shortest σ
    flat = s[:, 0] <= flatness * s[:, 1]
    return torch.where(flat[:, None], axis, torch.zeros_like(axis)).contiguous()
