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

Each particle stands for a square of the sensor plane one *grid cell* wide (``Pad.footprint``:
the grid spacing dx, at least one particle spacing), centred on the projection of its rest
position and shared among the taxels it overlaps in proportion to the overlap (a conservative
box-filter remap). Depth and shear are the overlap-weighted means over a taxel's surface
particles (empty taxels read 0), pressure the same over its soft particles; the force map sums
the overlap-weighted component along -z of the contact force on the particles [N], so it adds
up to the pad's total normal contact force within the layout; a taxel that would read a pull
(friction along a wall the pad wraps round) gives it to its pressed neighbours instead
(:func:`compressive_force`): no taxel reads below 0. A square one cell wide filters
out the period-dx pattern the grid imprints on the particles' motion and contact, at the price
of a one-cell blur (``bench pad`` measures the maps' L2 between resolutions).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .pad import Pad

__all__ = ["TaxelBinning", "tactile_maps", "map_tensors", "MAP_KEYS", "compressive_force"]

#: The maps a pad gives, in this order (:func:`tactile_maps`, the device read, the sensor).
MAP_KEYS = ("depth", "shear", "force", "pressure")


@dataclass
class TaxelBinning:
    """Precomputed share of every pad particle in each taxel: ``taxel`` [N, K] taxel indices
    (-1: outside the layout) and ``weight`` [N, K] the fraction of the particle's square
    footprint (``footprint`` wide, by default the pad's :attr:`Pad.footprint`, one grid cell) that
    falls in that taxel (K = up to 2 × 2 taxels per particle when the taxel pitch is at least the
    footprint)."""

    taxel: np.ndarray  # [N, K] int
    weight: np.ndarray  # [N, K] float, rows sum to the share of the footprint inside the layout
    rows: int
    cols: int

    @classmethod
    def for_pad(cls, pad: Pad, footprint: float | None = None) -> "TaxelBinning":
        """The binning of ``pad``'s particles, each a square ``footprint`` [m] wide (default:
        ``pad.footprint``) centred on its rest place in the sensor plane."""
        lay = pad.spec.layout
        s = pad.sensor_coords()
        width = float(pad.footprint if footprint is None else footprint)
        if not (np.isfinite(width) and width > 0.0):
            raise ValueError(f"TaxelBinning.for_pad: footprint={footprint!r} m must be positive")
        axes = []
        for a, (n, size) in enumerate(((lay.cols, lay.size[0]), (lay.rows, lay.size[1]))):
            pitch = size / n
            lo = (s[:, a] - 0.5 * width) / pitch + 0.5 * n  # footprint edges in taxel units
            hi = (s[:, a] + 0.5 * width) / pitch + 0.5 * n
            first = np.floor(lo).astype(int)
            span = int(np.ceil(width / pitch)) + 1
            idx = first[:, None] + np.arange(span)[None, :]
            overlap = np.minimum(hi[:, None], idx + 1) - np.maximum(lo[:, None], idx)
            frac = np.clip(overlap, 0.0, None) / (hi - lo)[:, None]
            ok = (idx >= 0) & (idx < n) & (frac > 0.0)
            axes.append((np.where(ok, idx, -1), np.where(ok, frac, 0.0)))
        (cx, wx), (ry, wy) = axes
        both = (ry[:, :, None] >= 0) & (cx[:, None, :] >= 0)
        taxel = np.where(both, ry[:, :, None] * lay.cols + cx[:, None, :], -1)
        weight = wy[:, :, None] * wx[:, None, :]
        n = len(s)
        return cls(taxel.reshape(n, -1), np.where(taxel >= 0, weight, 0.0).reshape(n, -1), lay.rows, lay.cols)

    def accumulate(self, mask: np.ndarray, values: np.ndarray | None = None) -> np.ndarray:
        """[rows·cols] Σ weight·value over the particles in ``mask`` (value 1 if None)."""
        idx, w = self.taxel[mask], self.weight[mask]
        if values is not None:
            w = w * np.asarray(values, np.float64)[mask][:, None]
        keep = idx >= 0
        return np.bincount(idx[keep], weights=w[keep], minlength=self.rows * self.cols)


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
    inside = (binning.taxel >= 0).any(axis=1)
    surf = pad.surface & inside
    count = binning.accumulate(surf)
    safe = np.where(count > 1e-9, count, 1.0)
    depth = binning.accumulate(surf, -un) / safe
    sx = binning.accumulate(surf, shear[:, 0]) / safe
    sy = binning.accumulate(surf, shear[:, 1]) / safe
    force = compressive_force(binning.accumulate(inside, fn), H, W)
    pressure = np.zeros(H * W)
    if stresses is not None:
        zw = R @ S[:, 2]
        snn = np.einsum("i,nij,j->n", zw, np.asarray(stresses, np.float64), zw)
        soft = inside & ~pad.kinematic
        cnt = binning.accumulate(soft)
        pressure = binning.accumulate(soft, -snn) / np.where(cnt > 1e-9, cnt, 1.0)
    return map_tensors(depth, sx, sy, force, pressure, H, W)


def _box_sum(x: torch.Tensor, r: int) -> torch.Tensor:
    """[..., H, W] the sum of ``x`` over the (2r + 1)² taxels around each taxel (those inside the
    layout): sums of the values themselves, no differences of running sums, so a window of
    zeros sums to exactly 0."""
    x = torch.nn.functional.pad(x, (r, r, r, r))
    return x.unfold(-2, 2 * r + 1, 1).sum(-1).unfold(-1, 2 * r + 1, 1).sum(-1)


def compressive_force(force, rows: int | None = None, cols: int | None = None):
    """The force map with every taxel ≥ 0 and, wherever the layout's total is positive, the same
    total, changed only where a taxel is negative (bit-identical otherwise).

    A taxel's raw force is the component along −z of the contact forces on its particles. Each
    point's contact is compressive (Signorini: λ ≥ 0, with friction |f_t| ≤ μλ), but where the
    contact normal lies across the sensor axis (a collider's side wall that the pad wraps round,
    or the pad's own rim and side faces) its −z component is the friction along that wall (of
    either sign) and the wall's tilt, and the edge taxels that hold only such points read a pull (tens of mN
    under random actions). That pull is part of the pad's net normal force (the map's total,
    :meth:`~gausstac_maniskill.cosim.GaussTacSim.pad_normal_force`), carried by the compressed
    contact next to it through the elastic layer; it is therefore taken from the positive taxels
    nearest it: each negative taxel takes its deficit from the positive taxels within Chebyshev
    distance r = 1, 2, … (in proportion to their force, none giving more than it has), until it
    is 0. Taxels that read 0 (no contact) stay 0, and the total is kept to rounding. Where the
    taxels within the layout pull more than they press (a pad touched only on its sides and
    dragged: no compressive load on the sensing face), the map reads 0 there.

    Args:
        force: the raw map, a float NumPy array [rows·cols] (then ``rows``, ``cols`` given; a
            float64 array comes back) or a torch tensor [..., rows, cols] (maps of a batch; one
            of the same dtype and device comes back, computed in float64 except on MPS).
    """
    if isinstance(force, np.ndarray):
        if not (force < 0).any():
            return force
        out = compressive_force(torch.from_numpy(np.asarray(force, np.float64).reshape(rows, cols)))
        return out.numpy().reshape(force.shape)
    if not bool((force < 0).any()):
        return force
    dtype = force.dtype
    f = force.to(torch.float32 if force.device.type == "mps" else torch.float64)
    H, W = f.shape[-2:]
    for r in range(1, max(H, W)):  # r = max(H, W) - 1: every window covers the whole layout
        deficit = (-f).clamp(min=0.0)
        if not bool((deficit > 0).any()):
            break
        supply = f.clamp(min=0.0)
        near = _box_sum(supply, r)  # what the positive taxels around each taxel hold
        ask = torch.where(near > 0, torch.minimum(deficit, near) / torch.where(near > 0, near, 1.0), 0.0)
        asked = _box_sum(ask, r)  # the share of its force each taxel is asked for, by all around it
        share = torch.where(asked > 1.0, 1.0 / torch.where(asked > 1.0, asked, 1.0), 1.0)  # never more than all
        # a taxel asked for more than it holds gives all it holds, in proportion to what each asked
        f = f - supply * asked * share + ask * _box_sum(supply * share, r)
        f = torch.where(deficit > 0, f.clamp(max=0.0), f)  # a pull at most repaid (not past 0 by rounding)
    return f.clamp(min=0.0).to(dtype)  # (the rounding left, and a pull no press within the layout balances)


def map_tensors(depth, shear_x, shear_y, force, pressure, rows: int, cols: int) -> dict[str, torch.Tensor]:
    """:func:`tactile_maps`' dict of float32 tensors from its maps as flat [rows·cols] arrays
    (taxel index row·cols + col)."""
    as_t = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))  # noqa: E731
    return {"depth": as_t(np.reshape(depth, (rows, cols))),
            "shear": as_t(np.stack([shear_x, shear_y], -1).reshape(rows, cols, 2)),
            "force": as_t(np.reshape(force, (rows, cols))),
            "pressure": as_t(np.reshape(pressure, (rows, cols)))}
