"""The finite-strain remainder of a voxel body's elements, in one Taichi kernel (float64).

:func:`~.hex.neo_hookean_forces` is the linear stiffness's forces K u plus this remainder: for
each element, the decoupled Neo-Hookean stresses less their linearisation,

    isochoric, at each integration point:  P − P_lin = μ J^(−2/3) (F − I₁/(3J) cof F) − 2μ dev ε,
    volumetric, at the element's centre:   P₀ − P₀_lin = K ln J₀ / J₀ cof F₀ − K tr(ε₀) I,

with F = I + ∇u, J = det F, I₁ = tr(FᵀF), cof F = J F⁻ᵀ and ε the small strain; each
integration point adds w P g_a to its element's node a (shape gradient g_a, volume w [m³]).

Which points an element integrates on (:class:`StrainPoints`, built once per body):

* a whole cube: its 2×2×2 Gauss points (where the stiffness's deviatoric part is integrated),
  each weighing an eighth of the cube;
* a cut cube at least :data:`~.hex.CUT_FINITE_SHARE` full: the same points, each weighing the
  material of its octant (the fill of the sub-cells there; its material sub-cells' 64 centres
  give the same forces to 0.03 % for up to twice the iterations);
* any other cube: none (it stays linear, :func:`~.hex.neo_hookean_remainder`).

One thread per element writes its own nodal forces; their sums on the nodes are taken on the
host in a fixed order, so a run repeats to the bit. Where Taichi runs on CUDA the same sums run
in torch on the GPU (:func:`remainder_forces_torch`): the kernel aborts there (:func:`_remainder`).
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti
import torch

from .. import backend
from ..kernel_launch import NDI, NDI2

__all__ = ["StrainPoints", "strain_points", "remainder_forces", "remainder_forces_torch"]

_F64_1 = ti.types.ndarray(dtype=ti.f64, ndim=1)
_F64_2 = ti.types.ndarray(dtype=ti.f64, ndim=2)
_F64_3 = ti.types.ndarray(dtype=ti.f64, ndim=3)

#: an element's rule: no finite-strain points, the Gauss points
LINEAR, GAUSS = -1, 0

@dataclass(frozen=True)
class StrainPoints:
    """Where each element of a body takes its finite-strain remainder (module docstring), in
    the kernel's dtypes."""

    element_nodes: np.ndarray  # [E, 8] int32, node of each corner
    rule: np.ndarray  # [E] int32: LINEAR or GAUSS
    weight: np.ndarray  # [E, 8] volume [m³] of material each Gauss point stands for (0: left out)
    centre_weight: np.ndarray  # [E] volume [m³] of the centre's volumetric term
    grads: np.ndarray  # [8, 8, 3] shape gradients [1/m] at the Gauss points
    centre_grads: np.ndarray  # [8, 3] shape gradients [1/m] at the centre


def strain_points(body, gauss: np.ndarray, octants, centre: np.ndarray,
                  finite_share: float) -> StrainPoints:
    """The :class:`StrainPoints` of ``body`` (:class:`~.hex.VoxelBody`): ``gauss`` [8, 8, 3] the
    shape gradients at the Gauss points, ``octants`` [n³, 8] the share of each sub-cell in each
    Gauss point's octant (cut cells; None for whole cubes), ``centre`` [8, 3] the shape gradients
    at the centre; cut cubes with a share of material (fill ≥ ½) below ``finite_share`` stay
    linear."""
    E = len(body.voxels)
    v = body.size ** 3
    weight = np.zeros((E, len(gauss)))
    rule = np.full(E, GAUSS, np.int32)
    if body.fill is None:
        weight[:] = v / len(gauss)
    else:
        whole = (body.fill == 1.0).all(1)
        material = body.fill >= 0.5
        cut = ~whole & (material.mean(1) >= finite_share)
        weight[whole] = v / len(gauss)
        weight[cut] = (np.where(material[cut], body.fill[cut], 0.0) * (v / len(octants))) @ octants
        rule[~whole & ~cut] = LINEAR
    return StrainPoints(np.ascontiguousarray(body.element_nodes, np.int32), rule, weight, weight.sum(1),
                        np.ascontiguousarray(gauss, np.float64), np.ascontiguousarray(centre, np.float64))


@ti.func
def _cofactor(F):
    """cof F = det(F) F⁻ᵀ of a 3×3 matrix."""
    c = ti.Matrix.zero(ti.f64, 3, 3)
    for i, j in ti.static(ti.ndrange(3, 3)):
        i1, i2, j1, j2 = (i + 1) % 3, (i + 2) % 3, (j + 1) % 3, (j + 2) % 3
        c[i, j] = F[i1, j1] * F[i2, j2] - F[i1, j2] * F[i2, j1]
    return c


@ti.kernel
def _remainder(element_nodes: NDI2, rule: NDI, weight: _F64_2, centre_weight: _F64_1,  # StrainPoints
               grads: _F64_3, centre_grads: _F64_2,
               moduli: _F64_1,  # (μ, K) [Pa]
               u: _F64_2, out: _F64_3, inverted: NDI):
    """out[e, a] = the remainder forces [N] of element e on its corner a, for node displacements
    u [V, 3] [m] (module docstring); inverted[0] = 1 where J ≤ 0 at a point that counts.

    The loops over an element's 8 points, corners and axes are all unrolled (``ti.static``): the
    body is straight-line code, because at ``opt_level=0`` (GAUSSTAC_COMPILE=fast) Taichi 1.7.4 on
    the CPU loses repeated additions to one entry inside a run-time loop nested in the parallel
    one. On Taichi's CUDA (H100, H200) this kernel aborts with a misaligned address in each of
    these forms: a run-time loop over the points summing a local 8×3 matrix, the same loop adding
    to ``out``, and this unrolled one; :func:`remainder_forces` takes torch there.
    """
    mu, bulk = moduli[0], moduli[1]
    eye = ti.Matrix.identity(ti.f64, 3)
    third = ti.cast(1.0, ti.f64) / 3.0  # in float64 (a literal's type is the default, float32)
    for e in range(rule.shape[0]):
        if rule[e] != LINEAR:
            ue = ti.Matrix.zero(ti.f64, 8, 3)  # the element's nodal displacements
            for a in ti.static(range(8)):
                for i in ti.static(range(3)):
                    ue[a, i] = u[element_nodes[e, a], i]
            # volumetric stress K ln J₀ F₀⁻ᵀ less its linearisation K tr(ε₀) I, one per element (F-bar)
            H0 = ti.Matrix.zero(ti.f64, 3, 3)
            for a in ti.static(range(8)):
                for i, j in ti.static(ti.ndrange(3, 3)):
                    H0[i, j] += ue[a, i] * centre_grads[a, j]
            F0 = eye + H0
            J0 = F0.determinant()
            P0 = ti.Matrix.zero(ti.f64, 3, 3)
            if J0 <= 0.0:
                inverted[0] = 1
            else:
                P0 = bulk * ti.log(J0) / J0 * _cofactor(F0) - bulk * H0.trace() * eye
            f = ti.Matrix.zero(ti.f64, 8, 3)  # the element's nodal forces
            w0 = centre_weight[e]
            for a in ti.static(range(8)):
                for i in ti.static(range(3)):
                    f[a, i] = w0 * (P0[i, 0] * centre_grads[a, 0] + P0[i, 1] * centre_grads[a, 1]
                                    + P0[i, 2] * centre_grads[a, 2])
            for p in ti.static(range(8)):  # the Gauss points
                w = weight[e, p]
                if w > 0.0:
                    H = ti.Matrix.zero(ti.f64, 3, 3)  # ∇u = Σ_a u_a ⊗ g_a
                    for a in ti.static(range(8)):
                        for i, j in ti.static(ti.ndrange(3, 3)):
                            H[i, j] += ue[a, i] * grads[p, a, j]
                    F = eye + H
                    J = F.determinant()
                    if J <= 0.0:
                        inverted[0] = 1
                    else:
                        I1 = (F * F).sum()
                        # isochoric Neo-Hookean stress less its linearisation 2μ dev ε
                        Pk = mu * ti.pow(J, -2.0 * third) * (F - I1 * third / J * _cofactor(F)) \
                            - mu * (H + H.transpose() - 2.0 * third * H.trace() * eye)
                        for a in ti.static(range(8)):
                            for i in ti.static(range(3)):
                                f[a, i] += w * (Pk[i, 0] * grads[p, a, 0] + Pk[i, 1] * grads[p, a, 1]
                                                + Pk[i, 2] * grads[p, a, 2])
            for a in ti.static(range(8)):
                for i in ti.static(range(3)):
                    out[e, a, i] = f[a, i]


def remainder_forces(points: StrainPoints, u: np.ndarray, mu: float, bulk: float) -> np.ndarray:
    """[V, 3] remainder forces [N] (module docstring) for node displacements ``u`` [V, 3] [m],
    shear and bulk moduli ``mu``, ``bulk`` [Pa]: the Taichi kernel where Taichi runs on the CPU;
    where it runs on CUDA, the same sums in torch on the GPU (:func:`remainder_forces_torch`),
    because the kernel aborts there with a misaligned address (Taichi 1.7.4, H100 and H200:
    :func:`_remainder`'s docstring).

    Raises:
        FloatingPointError: an element is inverted (J ≤ 0 at a point that counts).
    """
    if backend.ensure_init() != "cpu":
        return remainder_forces_torch(points, u, mu, bulk, device="cuda" if torch.cuda.is_available() else "cpu")
    if points.grads.shape[:2] != (8, 8):
        raise ValueError(f"the kernel takes 8 Gauss points of 8 corners, got grads {points.grads.shape}")
    fe = np.zeros((len(points.rule), 8, 3))
    inverted = np.zeros(1, np.int32)
    p = points
    _remainder(p.element_nodes, p.rule, p.weight, p.centre_weight, p.grads, p.centre_grads,
               np.array([mu, bulk], np.float64), np.ascontiguousarray(u, np.float64), fe, inverted)
    if inverted[0]:
        raise FloatingPointError("an element is inverted (J <= 0)")
    return _to_nodes(points, fe.transpose(0, 2, 1), len(u))


def remainder_forces_torch(points: StrainPoints, u: np.ndarray, mu: float, bulk: float,
                           device: str = "cpu") -> np.ndarray:
    """:func:`remainder_forces` in torch (float64) on ``device``; the nodal sums are taken on the
    host, in the kernel's fixed order. On the CPU its memory-bound [E, 8, 3, 3] temporaries make
    it much slower than the kernel."""
    sel = np.flatnonzero(points.rule == GAUSS)
    fe = np.zeros((len(points.rule), 3, 8))
    if len(sel):
        def t(x):
            return torch.as_tensor(np.ascontiguousarray(x), dtype=torch.float64, device=device)
        nodes = torch.as_tensor(points.element_nodes[sel], dtype=torch.int64, device=device)
        ut = t(u)[nodes].transpose(1, 2)  # [E, 3, 8]: each element's nodal displacements
        fe[sel] = _element_forces(ut, t(points.grads), t(points.centre_grads), t(points.weight[sel]),
                                  t(points.centre_weight[sel]), mu, bulk).cpu().numpy()
    return _to_nodes(points, fe, len(u))


def _to_nodes(points: StrainPoints, fe: np.ndarray, num_nodes: int) -> np.ndarray:
    """[V, 3] nodal sums of element forces ``fe`` [E, 3, 8] [N], in a fixed order."""
    f = np.zeros((num_nodes, 3))
    nodes = points.element_nodes.ravel()
    for i in range(3):
        f[:, i] = np.bincount(nodes, fe[:, i, :].ravel(), minlength=num_nodes)
    return f


def _element_forces(ut, G, G0, w, w0, mu, bulk):
    """[E, 3, 8] nodal forces [N] (torch) of elements with nodal displacements ``ut`` [E, 3, 8]
    [m]: the isochoric remainder at points of shape gradients ``G`` [points, 8, 3] and volumes
    ``w`` [E, points] [m³] (0: left out, taken undeformed), the volumetric one at the centre
    (``G0`` [8, 3], volume ``w0`` [E])."""
    eye = torch.eye(3, dtype=ut.dtype, device=ut.device)
    F = eye + ut[:, None] @ G[None]  # [E, points, 3, 3]
    F0 = eye + ut @ G0  # [E, 3, 3] at the centre
    F = torch.where((w <= 0.0)[..., None, None], eye, F)
    F0 = torch.where((w0 <= 0.0)[:, None, None], eye, F0)
    J, J0 = torch.linalg.det(F), torch.linalg.det(F0)
    if bool((J <= 0).any()) or bool((J0 <= 0).any()):
        raise FloatingPointError("an element is inverted (J <= 0)")
    cof = J[..., None, None] * torch.linalg.inv(F).transpose(-1, -2)
    cof0 = J0[:, None, None] * torch.linalg.inv(F0).transpose(-1, -2)
    I1 = (F * F).sum((-2, -1))
    H, H0 = F - eye, F0 - eye
    trH = H.diagonal(dim1=-2, dim2=-1).sum(-1)
    P = (mu * J ** (-2.0 / 3.0))[..., None, None] * (F - (I1 / (3.0 * J))[..., None, None] * cof) \
        - mu * (H + H.transpose(-1, -2) - (2.0 / 3.0) * trH[..., None, None] * eye)
    P0 = (bulk * torch.log(J0) / J0)[:, None, None] * cof0 \
        - bulk * H0.diagonal(dim1=-2, dim2=-1).sum(-1)[:, None, None] * eye
    return ((P @ G.transpose(1, 2)[None]) * w[:, :, None, None]).sum(1) + (P0 @ G0.T) * w0[:, None, None]
