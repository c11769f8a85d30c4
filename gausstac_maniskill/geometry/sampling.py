"""Seeding particles: a regular lattice inside a box or a watertight mesh.

Particles sit at the centres of a cubic lattice of spacing ``h`` [m], so a solid
of volume V gets V/h³ particles of volume h³ each, and its surface lies h/2
beyond the outermost particle centres.
"""
from __future__ import annotations

import numpy as np

from ..errors import AssetError, ConfigError


def box_particles(lo, hi, spacing: float) -> np.ndarray:
    """Lattice points [N, 3] filling the box [lo, hi] (metres), cell-centred.

    The box is split into round((hi-lo)/spacing) cells per axis, so its faces lie
    exactly half a spacing beyond the outer particles.
    """
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    if not (spacing > 0 and np.isfinite(spacing)):
        raise ConfigError(f"box_particles: spacing={spacing!r} m must be > 0")
    if lo.shape != (3,) or hi.shape != (3,) or np.any(hi <= lo):
        raise ConfigError(f"box_particles: need lo < hi (3 values each), got lo={lo}, hi={hi}")
    n = np.maximum(np.round((hi - lo) / spacing).astype(int), 1)
    axes = [lo[d] + (np.arange(n[d]) + 0.5) * spacing for d in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def mesh_particles(mesh, spacing: float, name: str = "mesh", with_query: bool = False):
    """Lattice points [N, 3] inside a watertight trimesh mesh (its own frame).

    With ``with_query=True`` also returns each point's distance to the surface [m]
    and the outward normal of the nearest face ([N], [N, 3]).

    Raises:
        AssetError: the mesh is not watertight or encloses no lattice point.
    """
    import trimesh

    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise AssetError(f"{name}: not a triangle mesh with faces")
    if not mesh.is_watertight:
        raise AssetError(f"{name}: mesh is not watertight (open edges); cannot tell inside from outside")
    lo, hi = mesh.bounds
    n = np.maximum(np.ceil((hi - lo) / spacing).astype(int), 1)
    axes = [lo[d] + (np.arange(n[d]) + 0.5) * spacing for d in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    from .mesh_query import query_mesh

    dist, normal, inside = query_mesh(mesh.vertices, mesh.faces, pts)  # winding number, in Taichi
    if not inside.any():
        raise AssetError(f"{name}: no particle fits inside the mesh at spacing {spacing:g} m "
                         f"(extents {np.round(mesh.extents, 5).tolist()} m); use a smaller spacing")
    if with_query:
        return pts[inside], dist[inside], normal[inside]
    return pts[inside]
