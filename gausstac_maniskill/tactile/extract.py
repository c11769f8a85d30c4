"""Tactile maps from a pad's particles: normal depth, 2-axis shear, per-taxel force.

Everything is expressed in the pad's link frame, so the maps do not change when
the hand moves without touching anything, and on the sensor's axes (x along the
finger, y across, z out of the pad), like a camera-based tactile sensor looking
at its gel. For a surface particle with rest position X and current link-frame
position x:

* displacement u = x − X;
* normal depth d = −u·z (positive when pushed into the pad) [m];
* shear s = (u·x, u·y) [m];
* pressure p = −zᵀσz, the compressive normal stress on the sensor axis, averaged
  over the soft particles of a taxel through the pad's thickness [Pa]. Unlike
  ``force`` it sees every contact, soft objects included.

Particles are assigned to taxels by the projection of their rest position on the
sensor plane; depth and shear are averaged over the surface particles of a taxel
(empty taxels read 0), and the force map sums, over all particles of a taxel, the
component along -z of the contact force the colliders exert on them [N]. So the
force map adds up to the total normal contact force on the pad within the layout.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .pad import Pad

__all__ = ["TaxelBinning", "tactile_maps"]


@dataclass
class TaxelBinning:
    """Precomputed taxel index of every pad particle (-1: outside the layout)."""

    taxel: np.ndarray  # [N] int
    rows: int
    cols: int

    @classmethod
    def for_pad(cls, pad: Pad) -> "TaxelBinning":
        lay = pad.spec.layout
        s = pad.sensor_coords()
        col = np.floor((s[:, 0] / lay.size[0] + 0.5) * lay.cols).astype(int)
        row = np.floor((s[:, 1] / lay.size[1] + 0.5) * lay.rows).astype(int)
        ok = (col >= 0) & (col < lay.cols) & (row >= 0) & (row < lay.rows)
        return cls(np.where(ok, row * lay.cols + col, -1), lay.rows, lay.cols)


def tactile_maps(pad: Pad, binning: TaxelBinning, positions: np.ndarray, link_pose: np.ndarray,
                 contact_forces: np.ndarray, stresses: np.ndarray | None = None) -> dict[str, torch.Tensor]:
    """Tactile maps of one pad.

    Args:
        pad: the pad (rest geometry in the link frame).
        binning: its :class:`TaxelBinning`.
        positions: [N, 3] current world positions of the pad's particles [m].
        link_pose: 4x4 current world pose of the pad's link.
        contact_forces: [N, 3] world contact force on each particle [N].
        stresses: optional [N, 3, 3] world Cauchy stress of each particle [Pa].

    Returns:
        ``{"depth": [H, W] m, "shear": [H, W, 2] m, "force": [H, W] N, "pressure": [H, W] Pa}``
        float32 tensors (pressure is zero without ``stresses``).
    """
    R, t = link_pose[:3, :3], link_pose[:3, 3]
    local = (np.asarray(positions, np.float64) - t) @ R
    S = pad.sensor_frame[:3, :3]
    u = (local - pad.rest) @ S  # displacement on the sensor axes
    un, shear = u[:, 2], u[:, :2]
    fn = -(np.asarray(contact_forces, np.float64) @ R) @ S[:, 2]  # pressing force along -z
    H, W = binning.rows, binning.cols
    n_tax = H * W
    idx = binning.taxel
    surf = pad.surface & (idx >= 0)
    count = np.bincount(idx[surf], minlength=n_tax).astype(np.float64)
    safe = np.maximum(count, 1.0)
    depth = np.bincount(idx[surf], weights=-un[surf], minlength=n_tax) / safe
    sx = np.bincount(idx[surf], weights=shear[surf, 0], minlength=n_tax) / safe
    sy = np.bincount(idx[surf], weights=shear[surf, 1], minlength=n_tax) / safe
    inside = idx >= 0
    force = np.bincount(idx[inside], weights=fn[inside], minlength=n_tax)
    pressure = np.zeros(n_tax)
    if stresses is not None:
        zw = R @ S[:, 2]
        snn = np.einsum("i,nij,j->n", zw, np.asarray(stresses, np.float64), zw)
        soft = (idx >= 0) & ~pad.kinematic
        cnt = np.maximum(np.bincount(idx[soft], minlength=n_tax), 1)
        pressure = np.bincount(idx[soft], weights=-snn[soft], minlength=n_tax) / cnt
    as_t = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))  # noqa: E731
    return {"depth": as_t(depth.reshape(H, W)),
            "shear": as_t(np.stack([sx, sy], -1).reshape(H, W, 2)),
            "force": as_t(force.reshape(H, W)),
            "pressure": as_t(pressure.reshape(H, W))}
