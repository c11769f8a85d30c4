"""Quasi-static bodies for the product's pads and for the thin-layer benchmark.

* :func:`pad_body`: a :class:`~gausstac_maniskill.tactile.pad.Pad` (link frame) as one cube
  element per soft particle (edge: the particle spacing), bonded where it meets the pad's
  kinematic particles, touched on the link mesh (the point ``depth`` along ``normal`` from
  each outermost particle, as ``GaussTacSim(pad_surface="mesh")``).
* :func:`layer_body`: a flat layer of thickness h bonded to a rigid base (a quarter, with
  symmetry planes x = 0 and y = 0, or the whole layer), touched at its top face.
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError
from .contact import QuasiStaticBody
from .hex import CORNERS, voxel_body

__all__ = ["pad_body", "pad_lattice", "layer_body", "collider_indenter"]


def pad_body(pad, E: float | None = None, nu: float | None = None, model: str = "linear") -> QuasiStaticBody:
    """The soft layer of ``pad`` as a quasi-static body in its link frame (metres).

    Args:
        pad: a :class:`~gausstac_maniskill.tactile.pad.Pad` (particles on a lattice of
            spacing ``pad.spacing``, as :func:`~gausstac_maniskill.tactile.pad.build_pad` makes).
        E, nu: Young's modulus [Pa] and Poisson's ratio (default: the pad's material).
        model: ``"linear"`` or ``"neo_hookean"`` (:class:`QuasiStaticBody`).
    """
    mat = pad.spec.material
    E = mat.E if E is None else E
    nu = mat.nu if nu is None else nu
    s = pad.spacing
    origin, ijk = pad_lattice(pad)
    soft = ~pad.kinematic
    body = voxel_body(ijk[soft], origin, s)
    # the bond: every node the soft elements share with a kinematic particle's cube
    span = ijk.max(0) + 2  # lattice nodes run 0 … max + 1 on each axis

    def key(v):
        return (v[..., 0] * span[1] + v[..., 1]) * span[2] + v[..., 2]

    fixed = np.isin(key(body.nodes), key(ijk[pad.kinematic][:, None, :] + CORNERS[None]))
    surface = np.flatnonzero(pad.surface[soft])
    rest = pad.rest[soft][surface]
    points = rest + pad.depth[soft][surface, None] * pad.normal[soft][surface]
    return QuasiStaticBody(body, E, nu, fixed, points, surface, name=f"pad {pad.name!r}", model=model)


def pad_lattice(pad) -> tuple[np.ndarray, np.ndarray]:
    """(origin [3] m, ijk [N, 3] int): the lattice of ``pad``'s particles (spacing
    ``pad.spacing``) and each particle's cell on it. Raises ConfigError off a lattice."""
    s = pad.spacing
    origin = pad.rest.min(0) - 0.5 * s
    ijk = np.round((pad.rest - origin) / s - 0.5).astype(np.int64)
    if np.abs((pad.rest - origin) / s - 0.5 - ijk).max() > 1e-6:
        raise ConfigError(f"pad {pad.name!r}: particles are not on a lattice of spacing {s:g} m")
    return origin, ijk


def layer_body(h: float, half_width: float, size: float, E: float, nu: float, model: str = "linear",
               quarter: bool = True) -> QuasiStaticBody:
    """A flat layer of thickness ``h`` [m] of cube elements of edge ``size`` [m], bonded to a
    rigid base at z = 0 and touched at the centres of its top faces (z = h); its outer faces
    are free. ``model`` as in :class:`QuasiStaticBody`.

    ``quarter`` (default): the quarter [0, W]² × [0, h] (W = ``half_width``) with frictionless
    symmetry planes x = 0 and y = 0; forces on it are a quarter of the whole layer's under a
    load symmetric about both planes. Otherwise the whole layer [−W, W]² × [0, h]."""
    nz = int(round(h / size))
    if nz < 1 or abs(nz * size - h) > 1e-6 * h:
        raise ConfigError(f"layer_body: h={h!r} m is not a whole number of elements of {size!r} m")
    nxy = math.ceil(half_width / size - 1e-9)
    span = np.arange(nxy) if quarter else np.arange(-nxy, nxy)
    i, j, k = np.meshgrid(span, span, np.arange(nz), indexing="ij")
    body = voxel_body(np.stack([i, j, k], -1).reshape(-1, 3), np.zeros(3), size)
    nodes = body.nodes
    fixed = np.zeros((len(nodes), 3), bool)
    fixed[nodes[:, 2] == 0] = True
    if quarter:
        fixed[nodes[:, 0] == 0, 0] = True
        fixed[nodes[:, 1] == 0, 1] = True
    top = np.flatnonzero(body.voxels[:, 2] == nz - 1)
    points = (body.voxels[top] + [0.5, 0.5, 1.0]) * size
    return QuasiStaticBody(body, E, nu, fixed, points, top, name="layer" if quarter else "whole layer", model=model)


def collider_indenter(collider, link_pose=None) -> "Indenter":
    """An MPM :class:`~gausstac_maniskill.mpm.colliders.Collider` (any shape, its ``pose`` in
    the world) as the :class:`~.contact.Indenter` a pad on a link at ``link_pose`` (4x4, world;
    default identity) sees: its signed distance in its own frame (the same Taichi code the MPM
    uses), its pose in the link frame, its friction."""
    import dataclasses

    from ..mpm.colliders import signed_distance
    from .contact import Indenter

    local = dataclasses.replace(collider, pose=np.eye(4))

    def local_sdf(q):
        phi, n = signed_distance(local, q)
        return phi.astype(np.float64), n.astype(np.float64)

    L = np.eye(4) if link_pose is None else np.asarray(link_pose, float)
    return Indenter(local_sdf, np.linalg.inv(L) @ collider.pose, collider.friction)
