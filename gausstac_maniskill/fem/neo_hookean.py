"""The finite-strain remainder of a voxel body's elements, in one Taichi kernel (float64).

:func:`~.hex.neo_hookean_forces` is the linear stiffness's forces K u plus this remainder: for
each element, the decoupled Neo-Hookean stresses less their linearisation,

    isochoric, at each integration point:  P − P_lin = μ J^(−2/3) (F − I₁/(3J) cof F) − 2μ dev ε,
    volumetric, at the element's centre:   P₀ − P₀_lin = K ln J₀ / J₀ cof F₀ − K tr(ε₀) I,

with F = I + ∇u, J = det F, I₁ = tr(FᵀF), cof F = J F⁻ᵀ and ε the small strain; each
integration point adds w P g_a to its element's node a (shape gradient g_a, volume w [m³]).

Which points an element integrates on (:class:`StrainPoints`, built once per body):

* a whole cube: its 2×2×2 Gauss points (where the stiffness's deviatoric part is integrated);
* a cut cube at least :data:`~.hex.CUT_FINITE_SHARE` full: its material sub-cells' centres,
  each weighted by its fill;
* any other cube: none (it stays linear, :func:`~.hex.neo_hookean_remainder`).

The kernel replaced a NumPy evaluation of the same sums (197 ms for the index pad's 14 005
elements at 0.5 mm: its [E, 8, 3, 3] temporaries were memory-bound; BENCHMARKS.md, "ninth
session"). One thread per element; the nodal sums are atomic adds, so on a parallel arch their
order, and the last bits of the forces, may vary from run to run.
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from .. import backend

__all__ = ["StrainPoints", "strain_points", "remainder_forces"]

_F64_1 = ti.types.ndarray(dtype=ti.f64, ndim=1)
_F64_2 = ti.types.ndarray(dtype=ti.f64, ndim=2)
_F64_4 = ti.types.ndarray(dtype=ti.f64, ndim=4)
_I32_1 = ti.types.ndarray(dtype=ti.i32, ndim=1)
_I32_2 = ti.types.ndarray(dtype=ti.i32, ndim=2)

#: an element's rule: no finite-strain points, the Gauss points, the sub-cell centres
LINEAR, GAUSS, SUBCELLS = -1, 0, 1

Elements = ti.types.argpack(  # one body's integration points (StrainPoints)
    element_nodes=_I32_2,  # [E, 8] node of each corner
    rule=_I32_1,  # [E] LINEAR, GAUSS or SUBCELLS
    weight=_F64_2,  # [E, P] volume [m³] of each point (0: left out)
    centre_weight=_F64_1,  # [E] volume [m³] of the centre's volumetric term
    grads=_F64_4,  # [2, P, 8, 3] shape gradients [1/m] of each rule's points
    centre_grads=_F64_2)  # [8, 3] shape gradients [1/m] at the centre


@dataclass(frozen=True)
class StrainPoints:
    """Where each element of a body takes its finite-strain remainder (module docstring):
    the arrays of :data:`Elements`, in the kernel's dtypes."""

    element_nodes: np.ndarray
    rule: np.ndarray
    weight: np.ndarray
    centre_weight: np.ndarray
    grads: np.ndarray
    centre_grads: np.ndarray

    def args(self):
        return Elements(element_nodes=self.element_nodes, rule=self.rule, weight=self.weight,
                        centre_weight=self.centre_weight, grads=self.grads, centre_grads=self.centre_grads)


def strain_points(body, gauss: np.ndarray, subcells, centre: np.ndarray,
                  finite_share: float) -> StrainPoints:
    """The :class:`StrainPoints` of ``body`` (:class:`~.hex.VoxelBody`): ``gauss`` [8, 8, 3] the
    shape gradients at the Gauss points, ``subcells`` [n³, 8, 3] at the sub-cell centres (cut
    cells; None for whole cubes), ``centre`` [8, 3] at the centre; cut cubes with a share of
    material (fill ≥ ½) below ``finite_share`` stay linear."""
    E = len(body.voxels)
    v = body.size ** 3
    P = len(gauss) if subcells is None else max(len(gauss), len(subcells))
    grads = np.zeros((2, P, 8, 3))
    grads[0, :len(gauss)] = gauss
    weight = np.zeros((E, P))
    rule = np.full(E, GAUSS, np.int32)
    if body.fill is None:
        weight[:, :len(gauss)] = v / len(gauss)
    else:
        grads[1, :len(subcells)] = subcells
        whole = (body.fill == 1.0).all(1)
        material = body.fill >= 0.5
        cut = ~whole & (material.mean(1) >= finite_share)
        weight[whole, :len(gauss)] = v / len(gauss)
        weight[cut, :len(subcells)] = np.where(material[cut], body.fill[cut], 0.0) * (v / len(subcells))
        rule[cut] = SUBCELLS
        rule[~whole & ~cut] = LINEAR
    return StrainPoints(np.ascontiguousarray(body.element_nodes, np.int32), rule, weight, weight.sum(1),
                        grads, np.ascontiguousarray(centre, np.float64))


@ti.func
def _cofactor(F):
    """cof F = det(F) F⁻ᵀ of a 3×3 matrix."""
    c = ti.Matrix.zero(ti.f64, 3, 3)
    for i, j in ti.static(ti.ndrange(3, 3)):
        i1, i2, j1, j2 = (i + 1) % 3, (i + 2) % 3, (j + 1) % 3, (j + 2) % 3
        c[i, j] = F[i1, j1] * F[i2, j2] - F[i1, j2] * F[i2, j1]
    return c


@ti.kernel
def _remainder(el: Elements, u: _F64_2, mu: ti.f64, bulk: ti.f64, out: _F64_2, inverted: _I32_1):
    """out[node] += the remainder forces [N] of every element on its nodes (module docstring);
    inverted[0] = 1 where J ≤ 0 at a point that counts."""
    eye = ti.Matrix.identity(ti.f64, 3)
    third = ti.cast(1.0, ti.f64) / 3.0  # in float64 (a literal's type is the default, float32)
    for e in range(el.rule.shape[0]):
        r = el.rule[e]
        if r == LINEAR:
            continue
        ue = ti.Matrix.zero(ti.f64, 8, 3)  # the element's nodal displacements [m]
        for a in ti.static(range(8)):
            for i in ti.static(range(3)):
                ue[a, i] = u[el.element_nodes[e, a], i]
        fe = ti.Matrix.zero(ti.f64, 8, 3)  # its nodal forces [N]
        for p in range(el.weight.shape[1]):
            w = el.weight[e, p]
            if w > 0.0:
                H = ti.Matrix.zero(ti.f64, 3, 3)  # ∇u = Σ_a u_a ⊗ g_a
                for a in ti.static(range(8)):
                    for i, j in ti.static(ti.ndrange(3, 3)):
                        H[i, j] += ue[a, i] * el.grads[r, p, a, j]
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
                        for i, j in ti.static(ti.ndrange(3, 3)):
                            fe[a, i] += w * Pk[i, j] * el.grads[r, p, a, j]
        w0 = el.centre_weight[e]
        H0 = ti.Matrix.zero(ti.f64, 3, 3)
        for a in ti.static(range(8)):
            for i, j in ti.static(ti.ndrange(3, 3)):
                H0[i, j] += ue[a, i] * el.centre_grads[a, j]
        F0 = eye + H0
        J0 = F0.determinant()
        if J0 <= 0.0:
            inverted[0] = 1
        else:
            # volumetric stress K ln J₀ F₀⁻ᵀ less its linearisation K tr(ε₀) I, one per element (F-bar)
            P0 = bulk * ti.log(J0) / J0 * _cofactor(F0) - bulk * H0.trace() * eye
            for a in ti.static(range(8)):
                for i, j in ti.static(ti.ndrange(3, 3)):
                    fe[a, i] += w0 * P0[i, j] * el.centre_grads[a, j]
        for a in ti.static(range(8)):
            for i in ti.static(range(3)):
                out[el.element_nodes[e, a], i] += fe[a, i]


def remainder_forces(points: StrainPoints, u: np.ndarray, mu: float, bulk: float) -> np.ndarray:
    """[V, 3] remainder forces [N] (module docstring) for node displacements ``u`` [V, 3] [m],
    shear and bulk moduli ``mu``, ``bulk`` [Pa].

    Raises:
        FloatingPointError: an element is inverted (J ≤ 0 at a point that counts).
    """
    backend.ensure_init()
    out = np.zeros((len(u), 3))
    inverted = np.zeros(1, np.int32)
    _remainder(points.args(), np.ascontiguousarray(u, np.float64), float(mu), float(bulk), out, inverted)
    if inverted[0]:
        raise FloatingPointError("an element is inverted (J <= 0)")
    return out
