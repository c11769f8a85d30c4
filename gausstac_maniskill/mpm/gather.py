"""Particle frames read on the device, for the splat camera: the affine frame
``x -> F_p x + x_p`` of each listed particle, written straight into a torch tensor.

A soft Gaussian rides on one particle (:mod:`gausstac_maniskill.splat.deform`): its frame is
the particle's deformation gradient F_p and position x_p. A sleeping pad's particles stay on
the device where the pad fell asleep while its link moves on; the renderer carries them with
the link's rigid motion D = [R | t] from then to now: (F, x) -> (R F, R x + t). One launch reads
the particles of every env and pad, so that a picture copies only the frames it needs (not the
whole particle state) and, on CUDA, nothing to the host.
"""

import taichi as ti
import torch

from .. import backend
from .kernels import NDM, NDV

_i32_1 = ti.types.ndarray(dtype=ti.i32, ndim=1)
_f32_3 = ti.types.ndarray(dtype=ti.f32, ndim=3)


@ti.kernel
def carried_frames(x: NDV, F: NDM, rows: _i32_1, carry: _i32_1, carries: _f32_3, frames: _f32_3):
    """frames[i] = D [F_p | x_p] + [0 | t] for particle p = rows[i], with D = [R | t] =
    carries[carry[i]] ([K, 3, 4]: row 0 is the identity, for particles that need no carry)."""
    for i in range(rows.shape[0]):
        p = rows[i]
        k = carry[i]
        R = ti.Matrix([[carries[k, a, b] for b in ti.static(range(3))] for a in ti.static(range(3))])
        t = ti.Vector([carries[k, a, 3] for a in ti.static(range(3))])
        M = R @ F[p]
        y = R @ x[p] + t
        for a in ti.static(range(3)):
            for b in ti.static(range(3)):
                frames[i, a, b] = M[a, b]
            frames[i, a, 3] = y[a]


def read_particle_frames(world, rows, carry, carries) -> torch.Tensor:
    """[P', 3, 4] float32 frames (F_p | x_p), carried, of the world particles ``rows`` ([P']
    int32 indices), on the Taichi arch's torch device, in one launch: ``carry`` [P'] picks each
    one's rigid motion in ``carries`` [K, 3, 4] (see :func:`carried_frames`). ``rows`` and
    ``carry`` may already lie on that device (kept by the caller: they rarely change)."""
    dev = backend.torch_device()
    out = torch.empty((len(rows), 3, 4), dtype=torch.float32, device=dev)
    if len(rows):
        state = world.device_state(("x", "F"))
        carried_frames(state["x"], state["F"], torch.as_tensor(rows, dtype=torch.int32, device=dev),
                       torch.as_tensor(carry, dtype=torch.int32, device=dev),
                       torch.as_tensor(carries, dtype=torch.float32, device=dev).contiguous(), out)
    return out
