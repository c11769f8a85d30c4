"""Constitutive models for MPM particles, as Taichi functions.

Every model returns the Kirchhoff stress τ = P Fᵀ = J σ [Pa], which is what the
MLS-MPM momentum transfer needs (force on node i: -Σ_p V0_p τ_p ∇w_ip).

Model ids (``MODEL_IDS``) index the per-material table built by
:func:`material_table`:

* ``neo_hookean`` — compressible Neo-Hookean,
  ψ = μ/2 (tr FᵀF - 3) - μ ln J + λ/2 (ln J)²,  τ = μ (F Fᵀ - I) + λ ln J · I.
  No SVD: the fast default for silicone pads. J is clamped to ≥ 0.05 inside the
  stress so an inverted particle pushes back instead of producing NaN.
* ``fixed_corotated`` — ψ = μ ‖F - R‖² + λ/2 (J - 1)², τ = 2μ (F - R) Fᵀ + λ (J - 1) J · I
  (R from the polar decomposition; robust under inversion).
* ``foam`` — elastoplastic sponge: fixed-corotated elasticity on Fe with the
  Stomakhin et al. (2013) return map (singular values of Fe clamped to
  [1-θc, 1+θs], the excess becomes plastic, Jp = det Fp) and hardening
  μ, λ ← μ, λ · exp(ξ (1 - Jp)).
"""

import numpy as np
import taichi as ti

from ..config import MODELS, Material

MODEL_IDS = {name: i for i, name in enumerate(MODELS)}
NEO_HOOKEAN, FIXED_COROTATED, FOAM = (MODEL_IDS[m] for m in ("neo_hookean", "fixed_corotated", "foam"))

#: Columns of the material table: mu, lam, model id, yield_compression, yield_stretch, hardening, density,
#: and 1 where the λ ln J term is solved implicitly on the grid's cells (``kernels.pressure_solve``).
TABLE_COLUMNS = ("mu", "lam", "model", "theta_c", "theta_s", "hardening", "density", "cell_pressure")
CELL_P = TABLE_COLUMNS.index("cell_pressure")
MIN_J = 0.05


def cell_pressure(material: Material, pressure: str) -> bool:
    """Whether ``material``'s λ ln J term is solved implicitly on cells under
    ``SolverSettings.pressure`` (Neo-Hookean materials only; the others stay explicit)."""
    return pressure == "implicit" and material.model == "neo_hookean"


def material_table(materials: list[Material], pressure: str = "explicit") -> np.ndarray:
    """Pack materials into a float32 table [M, 8] (columns ``TABLE_COLUMNS``).
    The density column is the physical density [kg/m^3]: it gives particles their weight."""
    table = np.zeros((max(len(materials), 1), 8), np.float32)
    for i, m in enumerate(materials):
        table[i] = (m.mu, m.lam, MODEL_IDS[m.model], m.yield_compression,
                    m.yield_stretch, m.hardening, m.density, float(cell_pressure(m, pressure)))
    return table


@ti.func
def polar_rotation(F):
    """Rotation R of the polar decomposition F = R S, with det R = +1."""
    U, sig, V = ti.svd(F)
    return U @ V.transpose()


@ti.func
def neo_hookean_shear(F, mu):
    """The μ part of the compressible Neo-Hookean Kirchhoff stress, μ(F Fᵀ - I) [Pa]."""
    return mu * (F @ F.transpose() - ti.Matrix.identity(ti.f32, 3))


@ti.func
def neo_hookean_stress(F, mu, lam):
    """Kirchhoff stress of the compressible Neo-Hookean model (J clamped at MIN_J)."""
    J = ti.max(F.determinant(), MIN_J)
    return neo_hookean_shear(F, mu) + lam * ti.log(J) * ti.Matrix.identity(ti.f32, 3)


@ti.func
def volumetric_stress(nh_only: ti.template(), J, Jp, mi, table: ti.template()):
    """The λ (bulk) term of the Kirchhoff stress, τ_vol = s·I, of material row ``mi`` at volume
    change J: s = λ ln J (Neo-Hookean), λ (J - 1) J (fixed-corotated; foam with hardening)."""
    s = 0.0
    lam = table[mi, 1]
    if ti.static(nh_only):
        s = lam * ti.log(J)
    else:
        model = ti.cast(table[mi, 2], ti.i32)
        if model == NEO_HOOKEAN:
            s = lam * ti.log(J)
        else:
            if model == FOAM:
                lam *= ti.exp(table[mi, 5] * (1.0 - Jp))
            s = lam * (J - 1.0) * J
    return s


@ti.func
def kirchhoff_stress(F, Jp, mu0, lam0, model, hardening):
    """Kirchhoff stress τ [Pa] of deformation gradient F (3x3) for one material."""
    tau = ti.Matrix.zero(ti.f32, 3, 3)
    if model == NEO_HOOKEAN:
        tau = neo_hookean_stress(F, mu0, lam0)
    else:
        mu, lam, R, J = _corotated_terms(F, Jp, mu0, lam0, model, hardening)
        tau = 2.0 * mu * (F - R) @ F.transpose() + lam * (J - 1.0) * J * ti.Matrix.identity(ti.f32, 3)
    return tau


@ti.func
def _corotated_terms(F, Jp, mu0, lam0, model, hardening):
    """(μ, λ) with foam hardening, polar rotation R and J of F, for the corotated models."""
    mu, lam = mu0, lam0
    if model == FOAM:
        h = ti.exp(hardening * (1.0 - Jp))
        mu, lam = mu0 * h, lam0 * h
    return mu, lam, polar_rotation(F), F.determinant()


@ti.func
def plastic_return(F, Jp, theta_c, theta_s):
    """Foam return map: clamp Fe's singular values; return (Fe, Jp)."""
    U, sig, V = ti.svd(F)
    new_Jp = Jp
    for d in ti.static(range(3)):
        s_old = sig[d, d]
        s_new = ti.min(ti.max(s_old, 1.0 - theta_c), 1.0 + theta_s)
        new_Jp *= s_old / s_new
        sig[d, d] = s_new
    return U @ sig @ V.transpose(), new_Jp


@ti.func
def strain_energy_density(F, Jp, mu0, lam0, model, hardening):
    """Elastic energy per unit rest volume ψ(F) [J/m^3]."""
    psi = 0.0
    if model == NEO_HOOKEAN:
        J = ti.max(F.determinant(), MIN_J)
        lnJ = ti.log(J)
        psi = 0.5 * mu0 * ((F.transpose() @ F).trace() - 3.0) - mu0 * lnJ + 0.5 * lam0 * lnJ * lnJ
    else:
        mu, lam, R, J = _corotated_terms(F, Jp, mu0, lam0, model, hardening)
        D = F - R
        psi = mu * (D * D).sum() + 0.5 * lam * (J - 1.0) ** 2
    return psi
