"""Thin-layer contact benchmark: a rigid sphere pressed into an elastic layer bonded to a rigid base.

``python -m gausstac_maniskill.bench thinlayer [--quick] [--dx 1e-3 5e-4] [--h 4e-3] [--nu 0.45]
[--bond surface nodes] [--sweep] [--out DIR]``

Set-up (SI units): a flat layer of thickness h (default 4 mm, the product pad),
E = 0.3 MPa, ν = 0.45 (``--nu``), ρ = 1100 kg/m³, on two grid cells of kinematic
particles bound to a fixed link (the rigid base the layer is bonded to), indented
by a rigid frictionless sphere of radius R to depth δ. As in
:mod:`~gausstac_maniskill.bench.hertz`, a quarter is simulated with frictionless
slip walls on x = 0 and y = 0 (forces ×4). The quarter is W = max(3a, a + 4h)
wide (a = √(Rδ), the Hertz contact radius), i.e. ≥ 3a and ≥ 4h of layer beyond the
contact edge; its outer faces are free (1.5·W changes F by < 0.8 %). The soft/kinematic interface lies half a cell between grid
node planes; the grid holds the layer at that bond surface (``SolverSettings.bond``, ghost
nodes; ``--bond nodes`` holds it at the pinned node planes instead, as before 2026-11-23:
see :func:`effective_thickness`).

Points: a/h = 0.3 … 3 at δ = 0.1·h (small strain, so a Neo-Hookean layer is
close to linear), R = a²/δ: small a/h needs a small sphere, a/h = 3 a nearly flat
one (R = 90·h). Each point loads quasi-statically: the sphere descends over
``ramp`` relaxation times 1/ζ and holds for ``hold`` more (ζ: the pad's dynamic
relaxation rate, :meth:`MPMWorld.add_group`); F = 4·(collider reaction) is the
mean over the last quarter of the hold and ``settle`` is its relative change
from the quarter before. Mass scaling is not used: with the hold in relaxation
times it would not save substeps (both the substep and 1/ζ scale with √ρ).

Reference solutions (all linear elasticity, frictionless paraboloid, bonded layer):

* **Dimitriadis** et al. 2002, Biophys. J. 82:2798, bonded sample, general ν:
  F = (4E/(3(1−ν²)))·√R·δ^{3/2}·[1 − (2α0/π)χ + (4α0²/π²)χ² − (8/π³)(α0³ + 4π²β0/15)χ³
  + (16α0/π⁴)(α0³ + 3π²β0/5)χ⁴], χ = √(Rδ)/h, α0 = −(1.2876 − 1.4678ν + 1.3442ν²)/(1−ν),
  β0 = (0.6387 − 1.0277ν + 1.5164ν²)/(1−ν). A series in χ of the solution of the
  layer's integral equation with the contact radius kept at the Hertz value
  √(Rδ): valid for χ up to about 1, small strain (δ ≪ h, δ ≪ R), linear
  elasticity, frictionless indenter, layer bonded to (not sliding on) a rigid
  substrate (the paper gives other α0, β0 for a not-bonded layer). We re-derived
  the series from that equation (kernel α0χ + 2β0χ³(x−y)², to O(χ⁴)) and it gives
  these coefficients; for ν = 0.5 they are 1.133, 1.283, 0.769 and **−0.0975**
  (the paper's ν = 0.5 polynomial prints +0.0975 for χ⁴ — a 0.2 % difference at
  χ = 0.5, 4.5 % at χ = 1; the general-ν form is used here). Shown as n/a for χ > 1.
* **layer**: the same problem solved numerically without truncation, for any a/h:
  the integral equation of an elastic layer bonded to a rigid base under a
  frictionless axisymmetric punch (the formulation of Hayes et al. 1972,
  J. Biomech. 5:541, after Lebedev & Ufliand 1958), φ(x) + (1/π)∫₋₁¹ k(x−y) φ(y) dy
  = δ − (a²/R)x², k(s) = ε∫₀^∞ [L(u) − 1] cos(εus) du, ε = a/h,
  L(u) = (2κ sinh 2u − 4u)/(2κ cosh 2u + 1 + κ² + 4u²), κ = 3 − 4ν; F = 2aE*∫₀¹φ,
  the contact radius a from φ(1) = 0 (no pressure singularity at the edge).
  Nyström on 32 Gauss points (converged to 1e-9 for a/h ≤ 10). This is our numerical
  solution, not a published closed form; it is checked in the tests against its
  limits: a/h → 0 gives Hertz; a/h ≫ 1 gives the thin compressible layer
  (uniaxial strain, F = π·M·R·δ²/h, M = E(1−ν)/((1+ν)(1−2ν))) and the thin
  incompressible layer (F = 2π·G·R²·δ³/h³, δ = a²/(4R), from the thin-layer
  lubrication approximation); its kernel's small-ε moments ∫(L−1), −¼∫u²(L−1)
  are Dimitriadis' α0, β0 to 0.6 % and 5 % at ν = 0.45 and 0.5.
  (Shull 2002, Mater. Sci. Eng. R 36:1, F = F_Hertz(a)(1 + β(a/h)³) for bonded
  incompressible layers, was not used: we could not check its constants here.)
  **The target (5 % for a/h ≤ 2) is checked against this solution**, not against the
  series: the series keeps the contact radius at √(Rδ), which is too large in a layer, and
  so falls below the untruncated solution of its own equation by 2 % at χ = 0.3, 6 % at
  0.5, 14 % at 1 (ν = 0.45). Under refinement the MPM force moves towards the layer
  solution, away from the series (2026-11-23, a/h = 0.5 / 1 / 2: +2.7 / +3.4 / +4.6 % at
  dx = 1 mm, +0.6 / +2.1 / +3.4 % at 0.5 mm; what is left at large a/h is the layer's
  10 % strain, where the Neo-Hookean law is stiffer than the linear solution).
* **Hertz** and **Sneddon** (half-space; :mod:`~gausstac_maniskill.bench.hertz`).
* **layer(h_eff)**: the layer solution at the MPM layer's effective thickness,
  measured by a uniaxial-strain (oedometer) compression of the same lattice
  (:func:`effective_thickness`), to separate the base's compliance from the
  contact's discretisation.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time

import numpy as np

from .. import backend
from .hertz import _progress, hertz_force, sneddon, warmup

E_LAYER = 3e5
NU_LAYER = 0.45
RHO_LAYER = 1100.0
H_LAYER = 4e-3
A_OVER_H = (0.3, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)
STRAIN = 0.1  # δ/h of every point
CHI_MAX_DIMITRIADIS = 1.0


# ---------------------------------------------------------------------------- theory
def dimitriadis_coefficients(nu: float, bonded: bool = True) -> tuple[float, float]:
    """α0, β0 of a layer bonded to (or, ``bonded=False``, sliding freely on) a rigid
    substrate (Dimitriadis et al. 2002)."""
    if not bonded:
        return -0.347 * (3 - 2 * nu) / (1 - nu), 0.056 * (5 - 2 * nu) / (1 - nu)
    alpha0 = -(1.2876 - 1.4678 * nu + 1.3442 * nu ** 2) / (1 - nu)
    beta0 = (0.6387 - 1.0277 * nu + 1.5164 * nu ** 2) / (1 - nu)
    return alpha0, beta0


def dimitriadis_series(nu: float, bonded: bool = True) -> np.ndarray:
    """Coefficients c0..c4 of F / F_Hertz(δ) = Σ c_k χ^k (general ν)."""
    a0, b0 = dimitriadis_coefficients(nu, bonded)
    pi = math.pi
    return np.array([1.0, -2 * a0 / pi, 4 * a0 ** 2 / pi ** 2,
                     -8 / pi ** 3 * (a0 ** 3 + 4 * pi ** 2 * b0 / 15),
                     16 * a0 / pi ** 4 * (a0 ** 3 + 3 * pi ** 2 * b0 / 5)])


def dimitriadis_bonded(E: float, nu: float, R: float, d, h: float):
    """Force [N] on a sphere of radius R [m] at depth d [m] in a bonded layer of thickness h [m]."""
    chi = np.sqrt(R * np.asarray(d)) / h
    return hertz_force(E / (1 - nu ** 2), R, d) * np.polyval(dimitriadis_series(nu)[::-1], chi)


_U, _WU = np.polynomial.legendre.leggauss(800)
_U, _WU = 9.0 * (_U + 1.0), 9.0 * _WU  # u in [0, 18]: L(u) - 1 < 1e-12 beyond
_X, _WX = np.polynomial.legendre.leggauss(32)
_X, _WX = 0.5 * (_X + 1.0), 0.5 * _WX  # x = r/a in [0, 1]


def _layer_kernel_weight(nu: float) -> np.ndarray:
    """Quadrature weights × (L(u) − 1) of the bonded layer's kernel (numerically safe form)."""
    k, e = 3 - 4 * nu, np.exp(-2 * _U)
    return -(2 * k * e + 4 * _U + 1 + k * k + 4 * _U ** 2) / (k * (1 / e + e) + 1 + k * k + 4 * _U ** 2) * _WU


def layer_solution(nu: float, a_over_h: float) -> tuple[float, float]:
    """Bonded layer under a frictionless paraboloid (radius R), contact radius a:
    returns (δ·R/a², F·R/(E*·a³)); (1, 4/3) is Hertz."""
    eps, mw = float(a_over_h), _layer_kernel_weight(nu)

    def k(s):
        return eps * (np.cos(eps * np.multiply.outer(s, _U)) @ mw)

    X, W = _X, _WX
    A = np.eye(len(X)) + (k(X[:, None] - X[None, :]) + k(X[:, None] + X[None, :])) * W / math.pi
    p1, p2 = np.linalg.solve(A, np.ones_like(X)), np.linalg.solve(A, X ** 2)
    k1 = (k(1 - X) + k(1 + X)) * W / math.pi
    d = (1 - k1 @ p2) / (1 - k1 @ p1)  # from φ(1) = 0
    return float(d), float(2 * W @ (d * p1 - p2))


def layer_force(E: float, nu: float, R: float, d: float, h: float) -> tuple[float, float]:
    """Exact linear-elastic force [N] and contact radius [m] of a bonded layer (see module doc)."""
    from scipy.optimize import brentq

    def depth(a):
        return layer_solution(nu, a / h)[0] * a * a / R - d

    a = brentq(depth, 1e-3 * math.sqrt(R * d), 3 * math.sqrt(R * d), xtol=1e-12 * h)
    return E / (1 - nu ** 2) * layer_solution(nu, a / h)[1] * a ** 3 / R, a


# ---------------------------------------------------------------------------- simulation
def _layer_world(h: float, dx: float, nu: float, half_width: float, offset: float = 0.5, fbar: bool = True,
                 bond: str = "surface", pressure: str = "explicit"):
    """World with a quarter layer [0, W]² × [z_top − h, z_top] on a 2-cell kinematic base.
    z_top is chosen so that the bond plane z_top − h lies ``offset`` cells above a node
    plane (default half a cell between node planes); ``fbar``, ``bond``, ``pressure``: SolverSettings."""
    from ..config import Material, SolverSettings
    from ..mpm import MPMWorld, box_particles

    settings = SolverSettings(dx=dx, gravity=(0.0, 0.0, 0.0), max_substeps=1_000_000, fbar=fbar, bond=bond,
                              pressure=pressure)
    hp = settings.particle_spacing
    if abs(h / hp - round(h / hp)) > 1e-6:
        raise ValueError(f"layer thickness h={h} m must be a multiple of the particle spacing {hp} m")
    z_bond = (math.floor(-h / dx) + offset) * dx
    z_top = z_bond + h
    world = MPMWorld(settings)
    world.add_link("base", np.eye(4))
    pts = box_particles([0.0, 0.0, z_bond - 2 * dx], [half_width, half_width, z_top], hp)
    group = world.add_group("layer", pts, Material(E=E_LAYER, nu=nu, density=RHO_LAYER), link="base",
                            kinematic=pts[:, 2] < z_bond)
    world.add_slip_wall(0, 0.0, "+")
    world.add_slip_wall(1, 0.0, "+")
    return world, group, z_top


def _press(world, collider, pose_at, depth: float, relax_rate: float, ramp: float, hold: float,
           steps_per_relax: int = 4) -> tuple[float, float, int, float]:
    """Move the collider to ``depth`` over ``ramp``/ζ seconds, hold ``hold``/ζ; returns
    (mean reaction z over the last quarter of the hold, relative change from the
    quarter before, substeps, solver wall time)."""
    dt = 1.0 / (relax_rate * steps_per_relax)
    n_ramp, n_hold = int(ramp * steps_per_relax), max(int(hold * steps_per_relax), 8)
    fz, substeps, wall = [], 0, 0.0
    for k in range(n_ramp + n_hold):
        world.set_collider_pose(collider, pose_at(depth * min(1.0, (k + 1) / n_ramp)))
        info = world.step(dt)
        substeps, wall = substeps + info.substeps, wall + info.wall_time
        if k >= n_ramp:
            fz.append(world.collider_wrench(collider)[0][2])
    q = len(fz) // 4
    last, before = float(np.mean(fz[-q:])), float(np.mean(fz[-2 * q:-q]))
    return last, abs(last - before) / max(abs(last), 1e-30), substeps, wall


def uniaxial_stress(strain: float, E: float = E_LAYER, nu: float = NU_LAYER) -> float:
    """Compressive Cauchy stress [Pa] of the compressible Neo-Hookean solid (the layer's
    material, :mod:`~gausstac_maniskill.mpm.materials`) in uniaxial strain, stretch
    s = 1 − ``strain``: σ = −[μ(s² − 1) + λ ln s]/s. Small strain: M·strain,
    M = E(1−ν)/((1+ν)(1−2ν)); at 5 % it is 7 % above that for ν = 0.45."""
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    s = 1.0 - strain
    return -(mu * (s * s - 1.0) + lam * math.log(s)) / s


def effective_thickness(h: float, dx: float, nu: float = NU_LAYER, strain: float = 0.05,
                        ramp: float = 20.0, hold: float = 40.0, offset: float = 0.5, bond: str = "surface",
                        pressure: str = "explicit") -> float:
    """Effective thickness [m] of the simulated bonded layer: a 2×2-cell column of the
    same lattice (bond plane ``offset`` cells above a node plane; ``bond``:
    SolverSettings.bond), slip walls on all four sides, compressed by a frictionless plate
    by δ = ``strain``·h (uniaxial strain). h_eff is the thickness whose Neo-Hookean
    uniaxial strain δ/h_eff gives the measured stress F/A (:func:`uniaxial_stress`);
    equal to h for a perfectly rigid bond at the right place."""
    from scipy.optimize import brentq

    from ..mpm import HalfSpace

    W = 2 * dx
    world, group, z_top = _layer_world(h, dx, nu, W, offset=offset, bond=bond, pressure=pressure)
    world.add_slip_wall(0, W, "-")
    world.add_slip_wall(1, W, "-")
    flip = np.diag([1.0, -1.0, -1.0])  # solid side of the half-space up

    def pose_at(d):
        T = np.eye(4)
        T[:3, :3], T[2, 3] = flip, z_top - d
        return T

    plate = world.add_collider(HalfSpace(pose=pose_at(0.0), friction=0.0))
    F, _, _, _ = _press(world, plate, pose_at, strain * h, group.relaxation, ramp, hold)
    sigma = F / (W * W)
    eps = brentq(lambda e: uniaxial_stress(e, E_LAYER, nu) - sigma, 1e-9, 0.9)
    return strain * h / eps


def run_point(R: float, d: float, h: float = H_LAYER, dx: float = 1e-3, nu: float = NU_LAYER,
              half_width: float | None = None, ramp: float = 10.0, hold: float = 20.0,
              bond: str = "surface", fbar: bool = True, pressure: str = "explicit") -> dict:
    """Press a sphere of radius R [m] to depth d [m] into the bonded layer; return the
    measured force with the reference solutions (forces in N, lengths in m)."""
    from ..mpm import Sphere
    from ..transforms import make_pose

    t0 = time.perf_counter()
    a = math.sqrt(R * d)
    W = half_width or max(3 * a, a + 4 * h)
    W = math.ceil(W / dx - 1e-9) * dx
    world, group, z_top = _layer_world(h, dx, nu, W, bond=bond, fbar=fbar, pressure=pressure)

    def pose_at(depth):
        return make_pose([0.0, 0.0, z_top + R - depth])

    sphere = world.add_collider(Sphere(radius=R, pose=pose_at(0.0), friction=0.0))
    fz, settle, substeps, solver_wall = _press(world, sphere, pose_at, d, group.relaxation, ramp, hold)
    E_star = E_LAYER / (1 - nu ** 2)
    chi = a / h
    F_layer, a_layer = layer_force(E_LAYER, nu, R, d, h)
    return dict(R=R, d=d, h=h, dx=dx, nu=nu, a=a, a_over_h=chi, chi=chi, a_over_dx=a / dx, half_width=W,
                particles=world.num_particles, substeps=substeps, settle=settle,
                wall=time.perf_counter() - t0, solver_wall=solver_wall, F_sim=4.0 * fz,
                F_dimitriadis=float(dimitriadis_bonded(E_LAYER, nu, R, d, h)) if chi <= CHI_MAX_DIMITRIADIS else None,
                F_layer=F_layer, a_layer=a_layer, F_hertz=float(hertz_force(E_star, R, d)),
                F_sneddon=sneddon(E_star, R, d)[0])


def run_case(h: float, dx: float, nu: float, a_over_h=A_OVER_H, strain: float = STRAIN,
             progress: bool = True, bond: str = "surface") -> dict:
    """All points at one resolution, plus the effective thickness and layer(h_eff)."""
    t0 = time.perf_counter()
    h_eff = effective_thickness(h, dx, nu, bond=bond)
    rows = []
    bar = _progress(len(a_over_h), f"dx={dx * 1e3:.2f} mm", progress)
    for r in a_over_h:
        d = strain * h
        row = run_point((r * h) ** 2 / d, d, h, dx, nu, bond=bond)
        row["F_layer_heff"] = layer_force(E_LAYER, nu, row["R"], d, h_eff)[0]
        rows.append(row)
        bar.update(1)
    bar.close()
    return dict(h=h, dx=dx, nu=nu, strain=strain, h_eff=h_eff, rows=rows, wall=time.perf_counter() - t0,
                bond=bond)


# ---------------------------------------------------------------------------- report
def _err(F, ref):
    return None if ref is None else 100.0 * (F / ref - 1.0)


def summarize(case: dict, a_over_h_max: float = 2.0) -> dict:
    """Max |error| [%] over a/h ≤ ``a_over_h_max`` against the layer solution (the target),
    against Dimitriadis' series where χ ≤ 1, and against layer(h_eff)."""
    rows = [r for r in case["rows"] if r["a_over_h"] <= a_over_h_max + 1e-9]
    dim = [r for r in rows if r["F_dimitriadis"] is not None]
    return dict(layer=max(abs(_err(r["F_sim"], r["F_layer"])) for r in rows),
                dimitriadis=max((abs(_err(r["F_sim"], r["F_dimitriadis"])) for r in dim), default=None),
                series_gap=min((_err(r["F_dimitriadis"], r["F_layer"]) for r in dim), default=None),
                layer_heff=max(abs(_err(r["F_sim"], r["F_layer_heff"])) for r in rows))


def format_table(case: dict) -> str:
    def f(x, fmt):
        return "n/a" if x is None else format(x, fmt)

    lines = [f"bond at the {case.get('bond', 'surface')}: "
             f"h = {case['h'] * 1e3:g} mm, dx = {case['dx'] * 1e3:g} mm, nu = {case['nu']}, delta = "
             f"{case['strain']:g} h; effective thickness of the simulated bond h_eff = {case['h_eff'] * 1e3:.2f} mm "
             f"(uniaxial compression); forces in N, errors of F_sim in %", "",
             "| R [mm] | δ [mm] | a/h = χ | a/dx | W [mm] | particles | F_sim | settle | F_Dimitriadis | err | "
             "F_layer | err | F_layer(h_eff) | err | F_Hertz | err | F_Sneddon | wall [s] |",
             "|" + "---|" * 18]
    for r in case["rows"]:
        flag = " ⚠" if r["a_over_dx"] < 2 else ""
        lines.append(
            f"| {r['R'] * 1e3:.1f} | {r['d'] * 1e3:.2f} | {r['a_over_h']:.2f} | {r['a_over_dx']:.1f}{flag} | "
            f"{r['half_width'] * 1e3:.0f} | {r['particles']} | {r['F_sim']:.4f} | {r['settle']:.0e} | "
            f"{f(r['F_dimitriadis'], '.4f')} | {f(_err(r['F_sim'], r['F_dimitriadis']), '+.1f')} | "
            f"{r['F_layer']:.4f} | {_err(r['F_sim'], r['F_layer']):+.1f} | {r['F_layer_heff']:.4f} | "
            f"{_err(r['F_sim'], r['F_layer_heff']):+.1f} | {r['F_hertz']:.4f} | {_err(r['F_sim'], r['F_hertz']):+.1f} | "
            f"{r['F_sneddon']:.4f} | {r['wall']:.1f} |")
    s = summarize(case)
    dim = "n/a (no point with χ ≤ 1)" if s["dimitriadis"] is None else (
        f"{s['dimitriadis']:.1f} % against Dimitriadis (χ ≤ 1; its series keeps the Hertz contact radius and "
        f"falls up to {-s['series_gap']:.1f} % below the layer solution at these points)")
    lines += ["", f"max |err| for a/h ≤ 2: {s['layer']:.1f} % against the layer solution (target 5 %), {dim}, "
              f"{s['layer_heff']:.1f} % against layer(h_eff). Wall time {case['wall']:.0f} s (incl. the h_eff run)."
              + (" ⚠: contact radius under 2 cells." if any(r["a_over_dx"] < 2 for r in case["rows"]) else "")]
    return "\n".join(lines)


def plot(cases: list[dict], path: str) -> None:
    """F / F_Hertz against a/h: MPM per resolution, and the reference solutions."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    c0 = cases[0]
    eps = np.linspace(0.02, 1.5 * max(r["a_over_h"] for r in c0["rows"]), 80)  # true contact radius / h
    ref = np.array([layer_solution(c0["nu"], e) for e in eps])  # (δR/a², F R/(E* a³))
    # χ = √(Rδ)/h = ε √(δR/a²) and F / F_Hertz(δ) = ¾ (F R/(E* a³)) / (δR/a²)^{3/2}
    ax.plot(eps * np.sqrt(ref[:, 0]), 0.75 * ref[:, 1] / ref[:, 0] ** 1.5, "k-", label="layer (exact linear)")
    cd = np.linspace(0.0, CHI_MAX_DIMITRIADIS, 50)
    ax.plot(cd, np.polyval(dimitriadis_series(c0["nu"])[::-1], cd), "b--", label="Dimitriadis 2002 (χ ≤ 1)")
    ax.axhline(1.0, color="grey", lw=0.8, label="Hertz")
    for c in cases:
        rows = c["rows"]
        ax.plot([r["a_over_h"] for r in rows], [r["F_sim"] / r["F_hertz"] for r in rows], "o",
                label=f"MPM dx={c['dx'] * 1e3:g} mm, bond at {c.get('bond', 'surface')} (h_eff={c['h_eff'] * 1e3:.1f} mm)")
        ax.plot([r["a_over_h"] for r in rows], [r["F_layer_heff"] / r["F_hertz"] for r in rows], "x", ms=5,
                color=ax.lines[-1].get_color(), label=f"layer at h_eff, dx={c['dx'] * 1e3:g} mm")
    ax.set_xlabel("a/h = χ = √(Rδ)/h")
    ax.set_ylabel("F / F_Hertz(δ)")
    ax.set_title(f"Bonded layer h={c0['h'] * 1e3:g} mm, δ={c0['strain']:g}h, E={E_LAYER / 1e6:g} MPa, ν={c0['nu']}")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


BOND_OFFSETS = tuple(k / 8 for k in range(8))  # bond plane positions between node planes [cells]
SWEEP_NU = (0.45, 0.48, 0.49, 0.499)


def sweep(h: float = H_LAYER, dx: float = 1e-3, progress: bool = True) -> str:
    """``--sweep``: (1) h_eff / h of the bonded layer at the 8 bond positions
    :data:`BOND_OFFSETS`, bond held at its surface and at the pinned node planes; (2) the force
    error against the layer solution at a/h = 0.5, 1, 2 over :data:`SWEEP_NU`, with F-bar and
    plain MLS-MPM (bond at its surface). Returns the two markdown tables."""
    from tqdm import tqdm

    lines = [f"h = {h * 1e3:g} mm, dx = {dx * 1e3:g} mm, nu = {NU_LAYER}: h_eff / h (Neo-Hookean uniaxial strain, "
             f"5 %) at bond offsets {', '.join(f'{o:g}' for o in BOND_OFFSETS)} cells above a node plane", "",
             "| bond held at | " + " | ".join(f"{o:g}" for o in BOND_OFFSETS) + " | mean | range |",
             "|" + "---|" * (len(BOND_OFFSETS) + 3)]
    bar = tqdm(total=2 * len(BOND_OFFSETS) + 6 * len(SWEEP_NU), desc="sweep", disable=not progress)
    for bond in ("nodes", "surface"):
        ratios = []
        for o in BOND_OFFSETS:
            ratios.append(effective_thickness(h, dx, NU_LAYER, offset=o, bond=bond) / h)
            bar.update(1)
        lines.append(f"| {bond} | " + " | ".join(f"{v:.3f}" for v in ratios) + f" | {np.mean(ratios):.3f} | "
                     f"{min(ratios):.3f}–{max(ratios):.3f} |")
    lines += ["", f"Force error [%] against the layer solution, a/h = 0.5 / 1 / 2, δ = {STRAIN:g} h, bond at its "
              "surface", "", "| ν | F-bar | plain MLS-MPM |", "|---|---|---|"]
    for nu in SWEEP_NU:
        cols = []
        for fbar in (True, False):
            errs = []
            for r in (0.5, 1.0, 2.0):
                d = STRAIN * h
                row = run_point((r * h) ** 2 / d, d, h, dx, nu, fbar=fbar)
                errs.append(_err(row["F_sim"], row["F_layer"]))
                bar.update(1)
            cols.append(" / ".join(f"{e:+.1f}" for e in errs))
        lines.append(f"| {nu} | {cols[0]} | {cols[1]} |")
    bar.close()
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m gausstac_maniskill.bench thinlayer", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="dx = 2 mm, h = 8 mm, a/h = 0.5, 1, 2")
    ap.add_argument("--dx", type=float, nargs="+", help="grid spacings [m] (default 1e-3)")
    ap.add_argument("--h", type=float, help=f"layer thickness [m] (default {H_LAYER:g})")
    ap.add_argument("--nu", type=float, default=NU_LAYER, help="Poisson's ratio of the layer")
    ap.add_argument("--sweep", action="store_true",
                    help="instead: h_eff over 8 bond positions (both --bond modes) and the force error over "
                         "nu = 0.45 ... 0.499 with and without F-bar")
    ap.add_argument("--bond", nargs="+", default=["surface"], choices=["surface", "nodes"],
                    help="SolverSettings.bond: the bond surface itself (default) or the pinned node planes")
    ap.add_argument("--arch", default=os.environ.get("GAUSSTAC_ARCH", "auto"), choices=["cpu", "cuda", "auto"])
    ap.add_argument("--out", default="out/bench_thinlayer", help="folder for thinlayer.md/.json/.png")
    args = ap.parse_args(argv)
    arch = backend.init(args.arch)
    h = args.h or (8e-3 if args.quick else H_LAYER)
    dxs = args.dx or ([2e-3] if args.quick else [1e-3])
    points = (0.5, 1.0, 2.0) if args.quick else A_OVER_H
    os.makedirs(args.out, exist_ok=True)
    print(f"Thin-layer benchmark on {arch} ({os.cpu_count()} cores): bonded layer h={h * 1e3:g} mm, "
          f"E={E_LAYER:g} Pa, nu={args.nu}, a/h={list(points)}, delta={STRAIN:g} h")
    t0 = time.time()
    warmup("particle")
    print(f"  kernels compiled in {time.time() - t0:.1f} s (not counted below)")
    if args.sweep:
        text = sweep(h, dxs[0])
        print("\n" + text)
        with open(os.path.join(args.out, "sweep.md"), "w") as fh:
            fh.write(text + "\n")
        print(f"\nwrote {args.out}/sweep.md  (total {time.time() - t0:.0f} s)")
        return 0
    cases = [run_case(h, dx, args.nu, points, bond=b) for b in args.bond for dx in dxs]
    tables = "\n\n".join(format_table(c) for c in cases)
    print()
    print(tables)
    with open(os.path.join(args.out, "thinlayer.md"), "w") as fh:
        fh.write(tables + "\n")
    with open(os.path.join(args.out, "thinlayer.json"), "w") as fh:
        json.dump(cases, fh)
    wrote = "thinlayer.md, thinlayer.json"
    try:
        plot(cases, os.path.join(args.out, "thinlayer.png"))
        wrote += ", thinlayer.png"
    except ImportError as exc:  # pragma: no cover - matplotlib is optional
        print(f"  (no plot: {exc})")
    print(f"\nwrote {args.out}/{{{wrote}}}  (total {time.time() - t0:.0f} s)")
    return 0
