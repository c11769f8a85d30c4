"""Thin-layer contact: a rigid frictionless sphere pressed into an MPM layer bonded to a rigid base.

``python -m gausstac_maniskill.bench thinlayer [--quick] [--dx 1e-3 5e-4] [--h 4e-3] [--nu 0.45]
[--bond surface nodes] [--sweep] [--out DIR]``

The layer (:func:`~gausstac_maniskill.bench.scenes.layer_world`: h = 4 mm, E = 0.3 MPa, ν = 0.45,
a quarter with slip walls, forces ×4) is pressed quasi-statically to δ = 0.1·h at a/h = 0.3 … 3
(:func:`~gausstac_maniskill.bench.scenes.run_point`). Prints the force against the bonded-layer
solution (the target: 5 % for a/h ≤ 2), Dimitriadis' series, Hertz and Sneddon
(:mod:`gausstac_maniskill.reference`), and against the layer solution at the effective thickness
the lattice simulates (:func:`~gausstac_maniskill.bench.scenes.effective_thickness`). ``--sweep``:
h_eff over bond positions and the force error over ν with and without F-bar.
"""
from __future__ import annotations

import os
import time

import numpy as np

from .. import backend
from ..reference import CHI_MAX_DIMITRIADIS, dimitriadis_series, layer_force, layer_solution
from .common import arch_option, cli, progress_bar, warmup, write_json, write_report
from .scenes import A_OVER_H, E_LAYER, H_LAYER, NU_LAYER, STRAIN, effective_thickness, run_point


# ---------------------------------------------------------------------------- simulation
def run_case(h: float, dx: float, nu: float, a_over_h=A_OVER_H, strain: float = STRAIN,
             progress: bool = True, bond: str = "surface") -> dict:
    """All points at one resolution, plus the effective thickness and layer(h_eff)."""
    t0 = time.perf_counter()
    h_eff = effective_thickness(h, dx, nu, bond=bond)
    rows = []
    bar = progress_bar(len(a_over_h), f"dx={dx * 1e3:.2f} mm", progress)
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
    ap = cli("thinlayer", __doc__)
    ap.add_argument("--quick", action="store_true", help="dx = 2 mm, h = 8 mm, a/h = 0.5, 1, 2")
    ap.add_argument("--dx", type=float, nargs="+", help="grid spacings [m] (default 1e-3)")
    ap.add_argument("--h", type=float, help=f"layer thickness [m] (default {H_LAYER:g})")
    ap.add_argument("--nu", type=float, default=NU_LAYER, help="Poisson's ratio of the layer")
    ap.add_argument("--sweep", action="store_true",
                    help="instead: h_eff over 8 bond positions (both --bond modes) and the force error over "
                         "nu = 0.45 ... 0.499 with and without F-bar")
    ap.add_argument("--bond", nargs="+", default=["surface"], choices=["surface", "nodes"],
                    help="SolverSettings.bond: the bond surface itself (default) or the pinned node planes")
    arch_option(ap)
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
        write_report(args.out, "sweep.md", text)
        print(f"\nwrote {args.out}/sweep.md  (total {time.time() - t0:.0f} s)")
        return 0
    cases = [run_case(h, dx, args.nu, points, bond=b) for b in args.bond for dx in dxs]
    tables = "\n\n".join(format_table(c) for c in cases)
    print()
    print(tables)
    write_report(args.out, "thinlayer.md", tables)
    write_json(args.out, "thinlayer.json", cases)
    wrote = "thinlayer.md, thinlayer.json"
    try:
        plot(cases, os.path.join(args.out, "thinlayer.png"))
        wrote += ", thinlayer.png"
    except ImportError as exc:  # pragma: no cover - matplotlib is optional
        print(f"  (no plot: {exc})")
    print(f"\nwrote {args.out}/{{{wrote}}}  (total {time.time() - t0:.0f} s)")
    return 0
