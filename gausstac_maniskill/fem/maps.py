"""The tactile maps of a linear pad as one matrix times its contact forces.

A linear pad's tactile maps (:func:`~gausstac_maniskill.tactile.extract.tactile_maps`: depth,
shear and pressure per taxel) are linear in its nodal displacements u, and u = K⁻¹ Nᵀ f is
linear in the contact forces f at its surface points. So the maps are r = M f, with
M = A K⁻¹ Nᵀ [4T, 3S] (T taxels, S surface points; A the readout of the maps from u). As K
is symmetric, M = (N K⁻¹ Aᵀ)ᵀ: 4T solves once per pad shape (1024 for a 16 × 16 layout),
instead of one solve of the whole body at every step. A step's maps then cost a product on
the loaded points' columns only.

:func:`map_readout` builds A from the same definitions as ``tactile_maps``: a particle's
displacement is the mean of its element's eight nodes, its stress the element's at its centre
(σ = λ tr ε I + 2μ ε, :func:`~.hex.centre_state`), each shared among taxels by its footprint
(:class:`~gausstac_maniskill.tactile.extract.TaxelBinning`). The force map needs no solve: it
bins the point forces directly, then moves any taxel's pull onto its pressed neighbours
(:func:`~gausstac_maniskill.tactile.extract.compressive_force`; :meth:`PadMaps.maps`).
"""
from __future__ import annotations

import numpy as np

from ..tactile.extract import compressive_force, map_tensors
from .signorini import _xyz_rows
from .hex import _gauss_gradients, _moduli

__all__ = ["map_readout", "PadMaps"]


def map_readout(pad, body, binning) -> "scipy.sparse.csr_matrix":
    """A [4T, 3V] (sparse): the depth, shear x, shear y and pressure maps (T = rows·cols
    taxels each, in that order; m, m, m, Pa) of ``pad`` read from the nodal displacements
    [V, 3] (m, node-major, link frame) of its linear ``body`` (:func:`~.pad.pad_body`: element e
    is the pad's e-th soft particle) under ``binning``."""
    import scipy.sparse as sp

    T = binning.rows * binning.cols
    S = pad.sensor_frame[:3, :3]  # sensor axes in the link frame (columns x, y, z)
    elem = np.full(pad.num_particles, -1)
    elem[np.flatnonzero(~pad.kinematic)] = np.arange(int((~pad.kinematic).sum()))  # element e: soft particle e
    inside = (binning.taxel >= 0).any(axis=1)
    surf = pad.surface & inside
    soft = ~pad.kinematic & inside

    def mean_rows(mask):  # 1 / (Σ weight) per taxel over the particles in mask (0 where empty)
        count = binning.accumulate(mask)
        return np.where(count > 1e-9, 1.0 / np.where(count > 1e-9, count, 1.0), 0.0)

    def entries(mask, per_node, row0, scale):
        """COO entries: each particle p of ``mask`` (a soft one) adds scale[t]·w_pt·per_node[a, i]
        to row row0 + t, column 3·node(p, a) + i, for its taxels t (weights w_pt)."""
        p = np.flatnonzero(mask & (elem >= 0))
        taxel, w = binning.taxel[p], binning.weight[p]  # [P, K]
        nodes = body.body.element_nodes[elem[p]]  # [P, 8]
        ok = np.broadcast_to((taxel >= 0)[:, :, None, None], (len(p), taxel.shape[1], 8, 3))
        rows = np.broadcast_to(row0 + taxel[:, :, None, None], ok.shape)
        cols = np.broadcast_to(3 * nodes[:, None, :, None] + np.arange(3), ok.shape)
        vals = (scale[np.maximum(taxel, 0)] * w)[:, :, None, None] * per_node[None, None]
        return rows[ok], cols[ok], vals[ok]

    parts = []
    inv_surf = mean_rows(surf)
    for row0, axis, sign in ((0, 2, -1.0), (T, 0, 1.0), (2 * T, 1, 1.0)):  # depth = −u·z, shear = (u·x, u·y)
        per_node = np.tile(sign * S[:, axis] / 8.0, (8, 1))  # u_p = the mean of the element's 8 nodes
        parts.append(entries(surf, per_node, row0, inv_surf))
    # pressure = −z·σ·z, σ = λ tr(ε) I + 2μ ε at the centre: −Σ_a u_a · (λ g_a + 2μ (g_a·z) z)
    mu, bulk = _moduli(body.E, body.nu)
    lam = bulk - 2.0 * mu / 3.0
    _, g = _gauss_gradients(body.body.size)  # [8, 3] shape gradients at the centre
    z = S[:, 2]
    per_node = -(lam * g + 2.0 * mu * (g @ z)[:, None] * z[None, :])
    parts.append(entries(soft, per_node, 3 * T, mean_rows(soft)))
    rows, cols, vals = (np.concatenate(a) for a in zip(*parts))
    return sp.csr_matrix((vals, (rows, cols)), shape=(4 * T, body.body.num_dofs))


class PadMaps:
    """A linear pad's tactile maps as M f (module docstring).

    Args:
        pad, body, binning: as :func:`map_readout`.
        point_particles: [S] the pad particle each surface point passes its force to.
        cache: keep M on disk (:func:`~.compliance.readout_responses`).
    """

    def __init__(self, pad, body, binning, point_particles: np.ndarray, cache: bool = True):
        from .compliance import readout_responses

        self.pad, self.binning = pad, binning
        self.point_particles = np.asarray(point_particles, np.int64)
        M = readout_responses(body, map_readout(pad, body, binning), cache=cache,
                              what=f"taxel readouts of pad {pad.name!r}")  # [4T, 3S] float32
        self.Mt = np.ascontiguousarray(M.T)  # [3S, 4T]: a loaded point's rows are contiguous
        self._inside = (binning.taxel >= 0).any(axis=1)  # particles whose footprint meets the layout

    def maps(self, force: np.ndarray) -> dict:
        """The maps (:func:`~gausstac_maniskill.tactile.extract.tactile_maps`'s dict of float32
        tensors) for contact forces ``force`` [S, 3] N on the surface points, link frame."""
        b, S = self.binning, self.pad.sensor_frame[:3, :3]
        T = b.rows * b.cols
        loaded = np.flatnonzero(np.abs(force).sum(1) > 0)
        r = force[loaded].ravel() @ self.Mt[_xyz_rows(loaded)].astype(np.float64)
        fn = np.zeros(self.pad.num_particles)  # pressing force along −z on each particle
        np.add.at(fn, self.point_particles[loaded], -(force[loaded] @ S[:, 2]))
        force = compressive_force(b.accumulate(self._inside, fn), b.rows, b.cols)
        return map_tensors(r[:T], r[T:2 * T], r[2 * T:3 * T], force, r[3 * T:], b.rows, b.cols)
