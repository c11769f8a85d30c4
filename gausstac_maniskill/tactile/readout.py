"""Tactile maps of every env's pads in one Taichi launch, read from the MPM world's device arrays.

The maps are those of :func:`~gausstac_maniskill.tactile.extract.tactile_maps` (the float64
NumPy reference, which the tests compare against), computed where the particles live:

* nothing of the particle state comes back to the host, only the maps ([B, H, W] per pad
  and map), written straight into a torch tensor on the device of the Taichi arch;
* every (env, pad) taxel is one thread that gathers its particles from a precomputed list
  (the taxel's share of each particle's footprint, one grid cell wide: :class:`TaxelBinning`),
  in a fixed order: no atomics, the same sums on any thread count.

Per taxel t of a pad on link pose (R, o), sensor axes S (columns x, y, z in the link
frame), for each particle i of the taxel with overlap weight w_i and rest place X_i (link
frame), world position x_i, contact impulse J_i of the control step Δt, Kirchhoff stress
τ_i and deformation gradient F_i:

* u_i = Sᵀ (Rᵀ (x_i − o) − X_i), the displacement on the sensor axes;
* depth = Σ w (−u_z) / Σ w, shear = Σ w (u_x, u_y) / Σ w over the surface particles;
* force = Σ w (−J_i · R S z) / Δt over all of the taxel's particles [N], then any taxel's pull
  moved onto its pressed neighbours (:func:`~.extract.compressive_force`, on the device);
* pressure = Σ w (−z_wᵀ σ_i z_w) / Σ w over the soft ones, σ = τ / det F, z_w = R S z [Pa].
"""

from typing import Sequence

import numpy as np
import taichi as ti
import torch

from .. import backend
from ..kernel_launch import NDF, NDF2, NDI, NDI2, NDM, NDV
from .extract import TaxelBinning, compressive_force
from .pad import Pad

__all__ = ["TactileReadout"]

SURFACE, SOFT = 1, 2  # flag bits of an entry: depth/shear from the surface layer, pressure from the soft part
CHANNELS = 5  # depth, shear x, shear y, force, pressure

Particles = ti.types.argpack(  # the MPM world's state arrays (all groups, all envs)
    x=NDV, impulse=NDV, tau=NDM, F=NDM)  # position [m], contact impulse of the step [N s], τ [Pa], F
Taxels = ti.types.argpack(  # per pad, the same in every env
    taxel_pad=NDI, taxel_start=NDI,  # per taxel (all pads' taxels in a row): its pad, its first entry
    entry_particle=NDI, entry_weight=NDF, entry_flags=NDI,  # per entry: particle (in its pad), overlap, flags
    entry_rest=NDV,  # the particle's rest place in the link frame [m]
    pad_axes=NDM)  # per pad: sensor axes in the link frame (columns x, y, z)
Slots = ti.types.argpack(  # per (env, pad), row env · n_pad + pad; uploaded at each read
    slot_rows=NDI2,  # (first world particle of the pad's group, awake 0/1)
    slot_pose=NDF2)  # the link's world pose: R row-major, then t [m]


@ti.kernel
def taxel_maps(state: Particles, tab: Taxels, slots: Slots, n_pad: ti.i32, inv_dt: ti.f32,
               out: ti.types.ndarray(dtype=ti.f32, ndim=3)):
    """out[env, taxel] = (depth, shear x, shear y, force, pressure) (module docstring);
    zeros for a sleeping pad."""
    for e, t in ti.ndrange(out.shape[0], out.shape[1]):
        p = tab.taxel_pad[t]
        s = e * n_pad + p
        acc = ti.Vector([0.0] * CHANNELS)
        w_surf, w_soft = 0.0, 0.0
        if slots.slot_rows[s, 1]:
            R = ti.Matrix([[slots.slot_pose[s, 3 * a + b] for b in ti.static(range(3))]
                           for a in ti.static(range(3))])
            o = ti.Vector([slots.slot_pose[s, 9 + a] for a in ti.static(range(3))])
            S = tab.pad_axes[p]
            z_w = R @ ti.Vector([S[0, 2], S[1, 2], S[2, 2]])  # the pad's outward normal, world
            first = slots.slot_rows[s, 0]
            for k in range(tab.taxel_start[t], tab.taxel_start[t + 1]):
                i = first + tab.entry_particle[k]
                w = tab.entry_weight[k]
                flags = tab.entry_flags[k]
                if flags & SURFACE:
                    u = S.transpose() @ (R.transpose() @ (state.x[i] - o) - tab.entry_rest[k])
                    acc[0] += -w * u[2]
                    acc[1] += w * u[0]
                    acc[2] += w * u[1]
                    w_surf += w
                acc[3] += -w * state.impulse[i].dot(z_w) * inv_dt  # pressing force along -z
                if flags & SOFT:
                    sigma = state.tau[i] / ti.max(state.F[i].determinant(), 1e-6)  # Cauchy
                    acc[4] += -w * z_w.dot(sigma @ z_w)
                    w_soft += w
        if w_surf > 1e-9:
            for c in ti.static(range(3)):
                acc[c] /= w_surf
        if w_soft > 1e-9:
            acc[4] /= w_soft
        for c in ti.static(range(CHANNELS)):
            out[e, t, c] = acc[c]


def _ndarray(arr: np.ndarray, dtype, vec: int = 0, mat: int = 0):
    """A Taichi ndarray holding ``arr`` (rows of vectors of length ``vec`` or matrices ``mat``²)."""
    arr = np.ascontiguousarray(arr)
    nd = (ti.Vector.ndarray(vec, dtype, shape=len(arr)) if vec else
          ti.Matrix.ndarray(mat, mat, dtype, shape=len(arr)) if mat else ti.ndarray(dtype, shape=arr.shape))
    nd.from_numpy(arr)
    return nd


class TactileReadout:
    """The tactile maps of pads in an :class:`~gausstac_maniskill.mpm.MPMWorld`, for several
    envs at once (see the module docstring).

    Args:
        world: the MPM world the pads' particles live in.
        pads: the pads, the same in every env (their rest geometry and sensor layout).
        slots: per env, per pad (in ``pads`` order), ``(group name, link name)`` in the world.
    """

    def __init__(self, world, pads: Sequence[Pad], slots: Sequence[Sequence[tuple[str, str]]]):
        backend.ensure_init()
        self.world = world
        self.pads = list(pads)
        self.slots = [list(env) for env in slots]
        if any(len(env) != len(self.pads) for env in self.slots):
            raise ValueError("TactileReadout: every env needs one (group, link) slot per pad")
        self._groups = [g for env in self.slots for g, _ in env]
        self._links = np.array([world.link_index(link) for env in self.slots for _, link in env], np.int64)
        self.offsets, rows = [0], []  # first taxel of each pad in the output; per-taxel entry lists
        taxel_pad, starts = [], [0]
        for p, pad in enumerate(self.pads):
            b = TaxelBinning.for_pad(pad)
            n_taxel = b.rows * b.cols
            n, k = np.nonzero(b.taxel >= 0)
            keep = b.weight[n, k] > 0.0
            n, k = n[keep], k[keep]
            order = np.lexsort((k, n, b.taxel[n, k]))  # by taxel, then particle: the reference's order
            n, k = n[order], k[order]
            flags = np.where(pad.surface[n], SURFACE, 0) | np.where(pad.kinematic[n], 0, SOFT)
            rows.append((n, b.weight[n, k], flags, pad.rest[n]))
            counts = np.bincount(b.taxel[n, k], minlength=n_taxel)
            starts.extend(starts[-1] + np.cumsum(counts))
            taxel_pad.extend([p] * n_taxel)
            self.offsets.append(self.offsets[-1] + n_taxel)
        n, w, f, rest = (np.concatenate(c) for c in zip(*rows))
        self._tab = dict(  # the Taxels pack's arrays (packs are built per launch: one held to exit errs)
            taxel_pad=_ndarray(np.array(taxel_pad, np.int32), ti.i32),
            taxel_start=_ndarray(np.array(starts, np.int32), ti.i32),
            entry_particle=_ndarray(n.astype(np.int32), ti.i32),
            entry_weight=_ndarray(w.astype(np.float32), ti.f32),
            entry_flags=_ndarray(f.astype(np.int32), ti.i32),
            entry_rest=_ndarray(rest.astype(np.float32), ti.f32, vec=3),
            pad_axes=_ndarray(np.array([pad.sensor_frame[:3, :3] for pad in self.pads], np.float32), ti.f32, mat=3))
        n_slot = len(self._groups)
        self._rows = ti.ndarray(ti.i32, shape=(max(n_slot, 1), 2))
        self._pose = ti.ndarray(ti.f32, shape=(max(n_slot, 1), 12))

    @property
    def num_envs(self) -> int:
        return len(self.slots)

    def read(self) -> torch.Tensor:
        """[B, T, 5] float32 on the Taichi arch's device: per env and taxel (all pads' taxels in
        a row, pad p's at ``offsets[p]:offsets[p + 1]``) depth [m], shear x, y [m], force [N],
        pressure [Pa] of the world's last step."""
        state = self.world.device_state(("x", "impulse", "tau", "F"))
        groups = [self.world.group(g) for g in self._groups]
        self._rows.from_numpy(np.array([(g.start, g.awake) for g in groups], np.int32).reshape(-1, 2))
        T = self.world.link_poses()[self._links]
        self._pose.from_numpy(np.concatenate([T[:, :3, :3].reshape(-1, 9), T[:, :3, 3]], 1).astype(np.float32))
        device = backend.torch_device()
        out = torch.empty((self.num_envs, self.offsets[-1], CHANNELS), dtype=torch.float32, device=device)
        dt = self.world.last_dt_ctrl
        taxel_maps(Particles(**state), Taxels(**self._tab), Slots(slot_rows=self._rows, slot_pose=self._pose),
                   len(self.pads), 1.0 / dt if dt > 0 else 0.0, out)
        return out

    def maps(self, device=None) -> dict[str, dict[str, torch.Tensor]]:
        """``{pad: {"depth": [B, H, W] m, "shear": [B, H, W, 2] m, "force": [B, H, W] N,
        "pressure": [B, H, W] Pa}}`` float32, contiguous, on ``device`` (the Taichi arch's by
        default): one launch for every env and pad."""
        out = self.read()
        if device is not None:
            out = out.to(device)
        B, res = self.num_envs, {}
        pull = bool((out[..., 3] < 0).any())  # one check (one device sync) for every pad
        for p, pad in enumerate(self.pads):
            lay = pad.spec.layout
            m = out[:, self.offsets[p]:self.offsets[p + 1]].reshape(B, lay.rows, lay.cols, CHANNELS)
            res[pad.name] = {"depth": m[..., 0].contiguous(), "shear": m[..., 1:3].contiguous(),
                             "force": compressive_force(m[..., 3].contiguous()) if pull else m[..., 3].contiguous(),
                             "pressure": m[..., 4].contiguous()}
        return res
