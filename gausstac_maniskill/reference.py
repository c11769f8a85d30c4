"""Closed-form and semi-analytic contact solutions that benchmarks and tests judge the solvers by.

All SI units (N, m, Pa). Linear elasticity unless said otherwise; the indenters are rigid and
frictionless. E* = E / (1 − ν²) is the plane-strain modulus against a rigid indenter
(:attr:`~gausstac_maniskill.config.Material.plane_strain_modulus`).

* :func:`hertz_force`, :func:`hertz_contact_radius`, :func:`hertz_peak_pressure`,
  :func:`hertz_pressure`: a sphere on an elastic half-space, small a/R (Hertz).
* :func:`sneddon`: the same without the small-a/R approximation (Sneddon).
* :func:`dimitriadis_bonded` (with :func:`dimitriadis_coefficients`, :func:`dimitriadis_series`):
  a sphere on a layer bonded to a rigid base, series in χ = √(Rδ)/h (Dimitriadis et al. 2002).
* :func:`layer_solution`, :func:`layer_force`: the bonded layer's integral equation solved
  numerically without truncation, for any a/h.
* :func:`uniaxial_stress`: the compressible Neo-Hookean solid in uniaxial strain (finite strain).

This module imports nothing of the package: any layer may use it.
"""
from __future__ import annotations

import math

import numpy as np

#: largest χ = √(Rδ)/h for which :func:`dimitriadis_bonded` is used (the series' range)
CHI_MAX_DIMITRIADIS = 1.0


# ---------------------------------------------------------------------------- half-space
def hertz_force(E_star: float, R: float, d):
    """Hertz normal force [N] of a rigid sphere of radius ``R`` [m] pressed to depth ``d`` [m]
    (scalar or array) into a half-space of plane-strain modulus ``E_star`` [Pa]:
    F = 4/3·E*·√R·d^{3/2}. Valid for a small contact radius a = √(Rd) ≪ R, small strain,
    frictionless contact, a body much larger than a."""
    return 4.0 / 3.0 * E_star * math.sqrt(R) * np.asarray(d) ** 1.5


def hertz_contact_radius(R: float, d: float) -> float:
    """Hertz contact radius a = √(R·d) [m] of a sphere of radius ``R`` [m] at depth ``d`` [m]
    (validity as :func:`hertz_force`)."""
    return math.sqrt(R * d)


def hertz_peak_pressure(F: float, a: float) -> float:
    """Hertz peak (centre) pressure p0 = 3F/(2πa²) [Pa] of force ``F`` [N] on contact radius
    ``a`` [m] (validity as :func:`hertz_force`)."""
    return 3 * F / (2 * math.pi * a ** 2)


def hertz_pressure(p0: float, a: float, r):
    """Hertz pressure p(r) = p0·√(1 − r²/a²) [Pa] at radii ``r`` [m] (array; 0 outside the contact
    radius ``a`` [m]), peak ``p0`` [Pa] (validity as :func:`hertz_force`)."""
    return p0 * np.sqrt(np.clip(1 - (r / a) ** 2, 0, None))


def sneddon(E_star: float, R: float, d: float) -> tuple[float, float]:
    """Sneddon's linear-elastic force [N] and contact radius [m] of a rigid sphere of radius
    ``R`` [m] at depth ``d`` [m] in a half-space of plane-strain modulus ``E_star`` [Pa]:
    d = (a/2)·ln((R+a)/(R−a)), F = (E*/2)·[(a² + R²)·ln((R+a)/(R−a)) − 2aR]. Exact for the
    spherical (not paraboloidal) profile, so valid for a/R not small (a < R); tends to Hertz as
    a/R → 0. Small strain, frictionless."""
    from scipy.optimize import brentq

    a = brentq(lambda a: a / 2 * math.log((R + a) / (R - a)) - d, 1e-9, R * (1 - 1e-9))
    F = E_star / 2 * ((a * a + R * R) * math.log((R + a) / (R - a)) - 2 * a * R)
    return F, a


# ---------------------------------------------------------------------------- bonded layer
def dimitriadis_coefficients(nu: float, bonded: bool = True) -> tuple[float, float]:
    """α0, β0 of Dimitriadis et al. 2002 (Biophys. J. 82:2798) for a layer of Poisson ratio
    ``nu`` bonded to (or, ``bonded=False``, sliding freely on) a rigid substrate:
    bonded α0 = −(1.2876 − 1.4678ν + 1.3442ν²)/(1 − ν), β0 = (0.6387 − 1.0277ν + 1.5164ν²)/(1 − ν);
    not bonded α0 = −0.347(3 − 2ν)/(1 − ν), β0 = 0.056(5 − 2ν)/(1 − ν). Dimensionless."""
    if not bonded:
        return -0.347 * (3 - 2 * nu) / (1 - nu), 0.056 * (5 - 2 * nu) / (1 - nu)
    alpha0 = -(1.2876 - 1.4678 * nu + 1.3442 * nu ** 2) / (1 - nu)
    beta0 = (0.6387 - 1.0277 * nu + 1.5164 * nu ** 2) / (1 - nu)
    return alpha0, beta0


def dimitriadis_series(nu: float, bonded: bool = True) -> np.ndarray:
    """Coefficients c0..c4 of F / F_Hertz(δ) = Σ c_k χ^k, χ = √(Rδ)/h (general ν):
    1, −2α0/π, 4α0²/π², −(8/π³)(α0³ + 4π²β0/15), (16α0/π⁴)(α0³ + 3π²β0/5).

    The series solves the layer's integral equation (kernel α0χ + 2β0χ³(x−y)², to O(χ⁴)) with
    the contact radius kept at the Hertz value √(Rδ). For ν = 0.5 (bonded) it gives 1.133,
    1.283, 0.769 and −0.0975; the paper's printed ν = 0.5 polynomial has +0.0975 for χ⁴ (a
    0.2 % difference at χ = 0.5, 4.5 % at χ = 1); the general-ν form is the one used here."""
    a0, b0 = dimitriadis_coefficients(nu, bonded)
    pi = math.pi
    return np.array([1.0, -2 * a0 / pi, 4 * a0 ** 2 / pi ** 2,
                     -8 / pi ** 3 * (a0 ** 3 + 4 * pi ** 2 * b0 / 15),
                     16 * a0 / pi ** 4 * (a0 ** 3 + 3 * pi ** 2 * b0 / 5)])


def dimitriadis_bonded(E: float, nu: float, R: float, d, h: float):
    """Force [N] on a rigid frictionless sphere of radius ``R`` [m] at depth ``d`` [m] in a layer
    of thickness ``h`` [m], Young's modulus ``E`` [Pa] and Poisson ratio ``nu``, bonded to a rigid
    base: F = (4E/(3(1−ν²)))·√R·d^{3/2}·Σ c_k χ^k (:func:`dimitriadis_series`), χ = √(Rd)/h.
    Valid for χ up to about 1 (:data:`CHI_MAX_DIMITRIADIS`), small strain (d ≪ h, d ≪ R). It
    keeps the contact radius at √(Rd), which is too large in a layer, so it falls below
    :func:`layer_force` as χ grows (by 2 % at χ = 0.3, 6 % at 0.5, 14 % at 1 for ν = 0.45)."""
    chi = np.sqrt(R * np.asarray(d)) / h
    return hertz_force(E / (1 - nu ** 2), R, d) * np.polyval(dimitriadis_series(nu)[::-1], chi)


#: Gauss–Legendre nodes u of the layer kernel's integral over [0, 18] (L(u) − 1 < 1e-12 beyond)
KERNEL_U, _WU = np.polynomial.legendre.leggauss(800)
KERNEL_U, _WU = 9.0 * (KERNEL_U + 1.0), 9.0 * _WU
_X, _WX = np.polynomial.legendre.leggauss(32)
_X, _WX = 0.5 * (_X + 1.0), 0.5 * _WX  # x = r/a in [0, 1]


def layer_kernel_weight(nu: float) -> np.ndarray:
    """Quadrature weights × (L(u) − 1) at :data:`KERNEL_U` of the bonded layer's kernel,
    L(u) = (2κ sinh 2u − 4u)/(2κ cosh 2u + 1 + κ² + 4u²), κ = 3 − 4ν (written in a form safe
    from overflow). Their small-ε moments ∫(L − 1) du and −¼∫u²(L − 1) du are Dimitriadis' α0
    and β0 (to 0.6 % and 5 % at ν = 0.45 and 0.5)."""
    k, e = 3 - 4 * nu, np.exp(-2 * KERNEL_U)
    return -(2 * k * e + 4 * KERNEL_U + 1 + k * k + 4 * KERNEL_U ** 2) / \
        (k * (1 / e + e) + 1 + k * k + 4 * KERNEL_U ** 2) * _WU


def layer_solution(nu: float, a_over_h: float) -> tuple[float, float]:
    """A layer bonded to a rigid base under a frictionless paraboloid of radius R, contact radius
    a, in dimensionless form: returns (δ·R/a², F·R/(E*·a³)); (1, 4/3) is Hertz.

    Solves the layer's integral equation (the formulation of Hayes et al. 1972, J. Biomech.
    5:541, after Lebedev & Ufliand 1958) φ(x) + (1/π)∫₋₁¹ k(x−y) φ(y) dy = δ − (a²/R)x²,
    k(s) = ε∫₀^∞ [L(u) − 1] cos(εus) du, ε = a/h (:func:`layer_kernel_weight`), by Nyström on
    32 Gauss points (converged to 1e-9 for a/h ≤ 10); F = 2aE*∫₀¹φ and δ from φ(1) = 0 (no
    pressure singularity at the contact edge). Linear elasticity, small strain, any a/h. Limits:
    a/h → 0 Hertz; a/h ≫ 1 the thin compressible layer (uniaxial strain, F = π·M·R·δ²/h,
    M = E(1−ν)/((1+ν)(1−2ν))) and the thin incompressible one (F = 2π·G·R²·δ³/h³, δ = a²/(4R))."""
    eps, mw = float(a_over_h), layer_kernel_weight(nu)

    def k(s):
        return eps * (np.cos(eps * np.multiply.outer(s, KERNEL_U)) @ mw)

    X, W = _X, _WX
    A = np.eye(len(X)) + (k(X[:, None] - X[None, :]) + k(X[:, None] + X[None, :])) * W / math.pi
    p1, p2 = np.linalg.solve(A, np.ones_like(X)), np.linalg.solve(A, X ** 2)
    k1 = (k(1 - X) + k(1 + X)) * W / math.pi
    d = (1 - k1 @ p2) / (1 - k1 @ p1)  # from φ(1) = 0
    return float(d), float(2 * W @ (d * p1 - p2))


def layer_force(E: float, nu: float, R: float, d: float, h: float) -> tuple[float, float]:
    """Linear-elastic force [N] and contact radius [m] of a rigid frictionless paraboloid of
    radius ``R`` [m] pressed to depth ``d`` [m] into a layer of thickness ``h`` [m] (Young's
    modulus ``E`` [Pa], Poisson ratio ``nu``) bonded to a rigid base: :func:`layer_solution` at
    the contact radius a that gives depth d. Validity as :func:`layer_solution`."""
    from scipy.optimize import brentq

    def depth(a):
        return layer_solution(nu, a / h)[0] * a * a / R - d

    a = brentq(depth, 1e-3 * math.sqrt(R * d), 3 * math.sqrt(R * d), xtol=1e-12 * h)
    return E / (1 - nu ** 2) * layer_solution(nu, a / h)[1] * a ** 3 / R, a


# ---------------------------------------------------------------------------- finite strain
def uniaxial_stress(strain: float, E: float, nu: float) -> float:
    """Compressive Cauchy stress [Pa] of the compressible Neo-Hookean solid
    (:mod:`~gausstac_maniskill.mpm.materials`; Young's modulus ``E`` [Pa], Poisson ratio ``nu``)
    in uniaxial strain, stretch s = 1 − ``strain``: σ = −[μ(s² − 1) + λ ln s]/s, μ = E/(2(1+ν)),
    λ = Eν/((1+ν)(1−2ν)). Finite strain, 0 ≤ strain < 1. Small strain: M·strain,
    M = E(1−ν)/((1+ν)(1−2ν)); at 5 % it is 7 % above that for ν = 0.45."""
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    s = 1.0 - strain
    return -(mu * (s * s - 1.0) + lam * math.log(s)) / s
