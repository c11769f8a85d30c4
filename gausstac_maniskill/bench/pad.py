"""Grid convergence of the product's fingertip pad (the Allegro index tip, default PadSpec).

``python -m gausstac_maniskill.bench pad [--quick] [--dx 1e-3 7.5e-4 5e-4] [--depths 5e-4 1e-3]
[--indenters plate sphere] [--pad-solver mpm|fem] [--curve] [--out DIR]``

The index pad (:func:`~gausstac_maniskill.bench.scenes.make_sim`) is pressed by a plate and a
5 mm sphere to each depth, held, slid 2 mm and held (:func:`~gausstac_maniskill.bench.scenes.press_pad`),
at each grid spacing. Prints the forces, contact areas and tactile maps against the finest grid
(relative L2) with a Richardson extrapolation of the forces, and the verdict for the default dx;
``--curve`` instead gives the speed-vs-error curve of the held force over grids, pseudo-mass
factors, patch radii and Courant numbers.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import asdict

import numpy as np

from .. import backend
from .common import arch_option, cli, write_json, write_report
from .scenes import FRICTION, FULL, MAPS, SLIDE, SPHERE_RADIUS, Protocol, index_spec
from .scenes import press_pad as run_case  # the pad's experiment (looked up here: speed_curve and run call it)

QUICK = Protocol(2, 2, 2)  # --quick
CURVE = Protocol(press=2, slide=0, hold=2)  # press and hold only (speed-vs-error curve)


# ---------------------------------------------------------------------------- numerics
def rel_l2(m, ref) -> float:
    """‖m − ref‖₂ / ‖ref‖₂ over all entries (any equal shapes); nan when ref is all zero."""
    m, ref = np.asarray(m, np.float64), np.asarray(ref, np.float64)
    n = float(np.linalg.norm(ref))
    return float(np.linalg.norm(m - ref)) / n if n > 0 else float("nan")


def richardson(h, f) -> dict:
    """Observed order and extrapolated value from three grids.

    Args:
        h: three grid spacings [m] (any order; the finest is h1).
        f: the quantity at those spacings.

    Returns:
        ``{"p": order or None, "f_star": extrapolated value or None, "status": str}``.
        With r21 = h2/h1, r32 = h3/h2 the order solves (f3−f2)/(f2−f1) =
        r21^p (r32^p − 1)/(r21^p − 1) (= r^p for a constant ratio), and
        f* = f1 + (f1 − f2)/(r21^p − 1). ``status``: ``"ok"``; ``"not monotone"`` when
        the differences change sign (or one is zero: order undefined); ``"not converging"``
        when p ≤ 0 (differences do not shrink with h; p is still reported).
    """
    (h1, f1), (h2, f2), (h3, f3) = sorted(zip(map(float, h), map(float, f)))
    e21, e32 = f2 - f1, f3 - f2
    if e21 == 0.0 or e32 == 0.0 or e32 / e21 < 0.0:
        return {"p": None, "f_star": None, "status": "not monotone"}
    a, b = math.log(h2 / h1), math.log(h3 / h2)
    target = math.log(e32 / e21)

    def g(p: float) -> float:  # ln of the ratio of differences predicted by order p
        if abs(p) < 1e-12:
            return math.log(b / a)
        return p * a + math.log(math.expm1(p * b) / math.expm1(p * a))

    lo, hi = -60.0, 60.0
    if not g(lo) < target < g(hi):
        return {"p": None, "f_star": None, "status": "no order in [-60, 60]"}
    for _ in range(200):  # g increases with p: bisection
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if g(mid) < target else (lo, mid)
    p = 0.5 * (lo + hi)
    if p <= 0.0:
        return {"p": p, "f_star": None, "status": "not converging"}
    return {"p": p, "f_star": f1 + (f1 - f2) / math.expm1(p * a), "status": "ok"}


# ---------------------------------------------------------------------------- analysis
def analyse(cases: list[dict], default_dx: float) -> dict:
    """Map errors vs the finest run, Richardson rows and the verdict for the default dx.

    Adds ``l2`` ({map: rel L2 vs the finest dx}) to every phase of ``cases`` and returns
    ``{"richardson": [...], "checks": [...], "verdict": str}``.
    """
    by = {}
    for c in cases:
        for ph in c["phases"]:
            by.setdefault((c["indenter"], ph["d"], ph["phase"]), {})[c["dx"]] = ph
    rows, checks = [], []
    for (ind, d, phase), runs in by.items():
        dxs = sorted(runs)
        ref = runs[dxs[0]]
        for ph in runs.values():
            ph["l2"] = {k: rel_l2(ph["maps"][k], ref["maps"][k]) for k in MAPS}
        default = runs.get(_match(default_dx, dxs))
        for q in ("Fn", "Ft") if phase == "slide" else ("Fn",):
            row = dict(indenter=ind, d=d, phase=phase, q=q, dx=dxs[:3], f=[runs[x][q] for x in dxs[:3]],
                       p=None, f_star=None, status="fewer than 3 grids", err_finest=None, err_star=None)
            if len(dxs) >= 3:
                row.update(richardson(row["dx"], row["f"]))
            if default is not None and default is not ref:
                row["err_finest"] = default[q] / ref[q] - 1
                row["err_star"] = default[q] / row["f_star"] - 1 if row["f_star"] else None
                checks.append((f"{ind} d={d * 1e3:g} mm {phase} {q}", abs(row["err_finest"]), 0.05))
            rows.append(row)
        if default is not None and default is not ref:
            checks += [(f"{ind} d={d * 1e3:g} mm {phase} {k} map L2", default["l2"][k], 0.10) for k in MAPS]
    if not any(_match(default_dx, [c["dx"]]) for c in cases):
        verdict = f"no verdict: the default dx = {default_dx * 1e3:g} mm was not run"
    elif not checks:
        verdict = f"no verdict: the default dx = {default_dx * 1e3:g} mm is the finest run"
    else:
        bad = [n for n, v, tol in checks if not v <= tol]
        verdict = ("PASS" if not bad else "FAIL") + (
            f": default dx = {default_dx * 1e3:g} mm vs finest {min(c['dx'] for c in cases) * 1e3:g} mm, "
            f"{len(checks) - len(bad)}/{len(checks)} checks within target (force 5 %, map L2 10 %)")
    return dict(richardson=rows, checks=[dict(name=n, value=v, tol=t) for n, v, t in checks], verdict=verdict)


def _match(x: float, values) -> float | None:
    return next((v for v in values if abs(v - x) <= 1e-9 + 1e-6 * x), None)


def _pct(x) -> str:
    return "–" if x is None or not np.isfinite(x) else f"{100 * x:+.1f}%"


def format_tables(cases: list[dict], ana: dict, default_dx: float) -> str:
    """Markdown tables: runs, per-phase measurements, Richardson, verdict."""
    mm = lambda v: f"{v * 1e3:g}"  # noqa: E731
    fem = all(c.get("pad_solver") == "fem" for c in cases)  # its own columns: elements, no substeps
    out = [f"Runs ({'wall time of the equilibrium solve' if fem else 'MPM wall time'} per 50 ms control step, "
           f"after the {'first' if fem else 'JIT'} step)", "",
           "| indenter | dx [mm] | " + ("elements [mm] | particles (elements) | solve" if fem else
                                       "particles (soft) | substeps / step | MPM") + " wall / step [ms] | build [s] |",
           "|---|---|---|---|---|---|"]
    for c in cases:
        middle = f"{c['spacing'] * 1e3:.4g} | {c['particles']} ({c['soft']})" if fem else \
            f"{c['particles']} ({c['soft']}) | {c['substeps']:.0f}"
        out.append(f"| {c['indenter']} | {mm(c['dx'])}{' (default)' if _match(default_dx, [c['dx']]) else ''} | "
                   f"{middle} | {c['step_ms']:.0f} | {c['build_s']:.1f} |")
    out += ["", "Per phase (hold-step means; Fn, Ft: reaction on the indenter in the sensor frame; Fn spread = "
            "(max−min)/mean over the hold; area: taxels with force > 1 mN | particles in contact, projected; "
            "L2: relative to the finest dx)", "",
            "| indenter | d [mm] | phase | dx [mm] | Fn [N] | force map sum [N] | Ft [N] | Fy [N] | Fn spread | "
            "area taxel [mm²] | area particle [mm²] | peak depth [mm] | L2 depth | L2 shear | L2 force |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    rows = sorted(((c, ph) for c in cases for ph in c["phases"]),
                  key=lambda t: (t[0]["indenter"], t[1]["d"], t[1]["phase"], -t[0]["dx"]))
    for c, ph in rows:
        out.append(f"| {c['indenter']} | {mm(ph['d'])} | {ph['phase']} | {mm(c['dx'])} | {ph['Fn']:.3f} | "
                   f"{ph['F_map']:.3f} | {ph['Ft']:.3f} | {ph['Fy']:.3f} | {100 * ph['F_spread']:.1f}% | "
                   f"{ph['area_taxel'] * 1e6:.1f} | {ph['area_particle'] * 1e6:.1f} | {ph['peak_depth'] * 1e3:.3f} | "
                   + " | ".join(f"{ph['l2'][k]:.3f}" for k in MAPS) + " |")
    out += ["", "Richardson extrapolation from the three finest grids (f1 finest); default dx error vs the "
            "finest run and vs f*", "",
            "| indenter | d [mm] | phase | quantity | dx [mm] | f [N] | order p | f* [N] | default vs finest | "
            "default vs f* |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in ana["richardson"]:
        p = r["status"] if r["p"] is None else (f"{r['p']:.2f}" + ("" if r["status"] == "ok" else f" ({r['status']})"))
        fs = "–" if r["f_star"] is None else f"{r['f_star']:.3f}"
        out.append(f"| {r['indenter']} | {mm(r['d'])} | {r['phase']} | {r['q']} | "
                   f"{', '.join(mm(x) for x in r['dx'])} | {', '.join(f'{v:.3f}' for v in r['f'])} | {p} | {fs} | "
                   f"{_pct(r['err_finest'])} | {_pct(r['err_star'])} |")
    out += ["", ana["verdict"]]
    return "\n".join(out)


def plot_maps(cases: list[dict], out_dir: str) -> list[str]:
    """One PNG per (indenter, depth, phase): depth and force maps, one column per dx."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: no map images")
        return []
    paths = []
    keys = sorted({(c["indenter"], ph["d"], ph["phase"]) for c in cases for ph in c["phases"]})
    for ind, d, phase in keys:
        runs = sorted(((c["dx"], ph) for c in cases if c["indenter"] == ind for ph in c["phases"]
                       if ph["d"] == d and ph["phase"] == phase), key=lambda t: -t[0])
        fig, axes = plt.subplots(2, len(runs), figsize=(2.6 * len(runs) + 1, 5.2), squeeze=False)
        for row, (key, scale, unit) in enumerate((("depth", 1e3, "mm"), ("force", 1.0, "N"))):
            vmax = max(float(ph["maps"][key].max()) * scale for _, ph in runs) or 1.0
            for col, (dx, ph) in enumerate(runs):
                im = axes[row, col].imshow(ph["maps"][key] * scale, origin="lower", vmin=0, vmax=vmax, cmap="viridis")
                axes[row, col].set_title(f"{key}, dx={dx * 1e3:g} mm", fontsize=8)
                axes[row, col].set_xticks([])
                axes[row, col].set_yticks([])
            fig.colorbar(im, ax=axes[row, :].tolist(), label=f"{key} [{unit}]", shrink=0.8)
        fig.suptitle(f"{ind}, d = {d * 1e3:g} mm, {phase}")
        path = os.path.join(out_dir, f"pad_{ind}_{d * 1e3:g}mm_{phase}.png")
        fig.savefig(path, dpi=90)
        plt.close(fig)
        paths.append(path)
    return paths


def run(dxs, indenters=("plate", "sphere"), depths=(0.5e-3, 1.0e-3), thickness=None, protocol=FULL,
        friction=FRICTION, progress=True, pad_solver: str = "mpm", fem_model: str = "linear",
        fem_precompute: bool | None = None) -> list[dict]:
    """All (dx, indenter) cases, coarsest first, with one tqdm bar over every control step
    (``pad_solver``, ``fem_model``, ``fem_precompute``: :func:`run_case`)."""
    from tqdm import tqdm

    per_case = 1 + len(depths) * (protocol.press + protocol.slide + 2 * protocol.hold)
    cases = []
    with tqdm(total=per_case * len(dxs) * len(indenters), disable=not progress, desc="pad") as bar:
        for dx in sorted(dxs, reverse=True):
            for ind in indenters:
                bar.set_description(f"{ind} dx={dx * 1e3:g} mm")
                cases.append(run_case(dx, ind, depths, thickness, protocol, friction, bar, pad_solver=pad_solver,
                                      fem_model=fem_model, fem_precompute=fem_precompute))
    return cases


def speed_curve(points, indenter: str = "sphere", depth: float = 1e-3, progress: bool = True,
                pad_surface: str = "mesh", hold: int = CURVE.hold, pad_solver: str = "mpm",
                fem_model: str = "linear", fem_precompute: bool | None = None) -> dict:
    """Speed against force error on the product pad (``bench pad --curve``).

    ``points``: (dx [m], mass_scaling, patch_radius [m] or None[, Courant number]) tuples; each
    presses ``indenter`` ``depth`` [m] into
    the index pad (:data:`CURVE` protocol, with ``hold`` held steps) and records the held normal
    force Fn [N] (mean over the second half of the hold, and its spread over the whole hold), the
    MPM wall time per 50 ms step [ms], and the normal force read from the pad's stress
    (:meth:`GaussTacSim.pad_stress_force`, virtual work; and the pressure-map
    estimate :meth:`GaussTacSim.pad_pressure_force`), for the consistency of the readings.
    The reference is the Richardson extrapolation of Fn over the three finest grids at the
    default mass scaling when it gives an order in (0.5, 4), else the finest run; errors
    are Fn / reference − 1. ``pad_solver``, ``fem_model``, ``fem_precompute``: :func:`run_case`'s (the pad solved at
    equilibrium has no mass scaling, patch or Courant number: give it dx points only).
    Returns ``{"runs": [...], "reference": float, "reference_from": str}``.
    """
    from tqdm import tqdm

    runs = []
    protocol = Protocol(press=CURVE.press, slide=0, hold=hold)
    with tqdm(total=len(points) * (1 + protocol.press + protocol.hold), disable=not progress, desc="curve") as bar:
        for dx, ms, pr, cfl in sorted(((tuple(p) + (None,))[:4] for p in points),
                                      key=lambda t: (-t[0], t[1], t[2] or 0.0, t[3] or 0.0)):
            bar.set_description(f"dx={dx * 1e3:g} mm, mass x{ms:g}, patch {pr}, cfl {cfl}")
            c = run_case(dx, indenter, [depth], protocol=protocol, bar=bar, mass_scaling=ms, pad_surface=pad_surface,
                         patch_radius=pr, cfl=cfl, pad_solver=pad_solver, fem_model=fem_model,
                         fem_precompute=fem_precompute)
            runs.append(dict(dx=dx, pad_solver=pad_solver, spacing=c["spacing"], mass_scaling=ms, patch_radius=pr,
                             cfl=c.get("cfl", cfl), active=c["active"],
                             particles=c["particles"],
                             substeps=c["substeps"],
                             step_ms=c["step_ms"], held_ms=c["phases"][0]["wall_end"],
                             held_substeps=c["phases"][0]["substeps_end"],
                             Fn=c["phases"][0]["Fn_end"], F_spread=c["phases"][0]["F_spread"],
                             F_stress=c["phases"][0]["F_stress_end"], F_pressure=c["phases"][0]["F_pressure_end"]))
    from ..config import SolverSettings

    default_ms = SolverSettings().mass_scaling
    default_cfl = SolverSettings().cfl
    base = sorted((r for r in runs if r["mass_scaling"] == default_ms and r["patch_radius"] is None
                   and r["cfl"] in (None, default_cfl)), key=lambda r: r["dx"])
    ref, src = base[0]["Fn"], f"finest run (dx = {base[0]['dx'] * 1e3:g} mm)"
    if len(base) >= 3:
        rich = richardson([r["dx"] for r in base[:3]], [r["Fn"] for r in base[:3]])
        if rich["status"] == "ok" and 0.5 < rich["p"] < 4.0:
            ref = rich["f_star"]
            grids = ", ".join(f"{r['dx'] * 1e3:g}" for r in base[:3])
            src = f"Richardson over dx = {grids} mm (order {rich['p']:.2f})"
    for r in runs:
        r["err"] = r["Fn"] / ref - 1.0
    return dict(runs=runs, reference=ref, reference_from=src)


def format_curve(curve: dict, indenter: str, depth: float) -> str:
    """Markdown table of :func:`speed_curve`, cheapest first (the MPM's columns, or the pad at
    equilibrium's: no pseudo-mass, Courant number, patch or substeps)."""
    out = [f"Speed against error: index pad, {indenter} pressed {depth * 1e3:g} mm, held normal force vs "
           f"reference {curve['reference']:.4f} N ({curve['reference_from']})", ""]
    fem = all(r.get("pad_solver") == "fem" for r in curve["runs"])
    if fem:
        out += ["| dx [mm] | elements [mm] | elements in the 4 mm layer | particles | solve wall / 50 ms step [ms] | "
                "second half of the hold: ms / step | Fn [N] | error | pressure map × area / contact |",
                "|---|---|---|---|---|---|---|---|---|"]
    else:
        out += ["| dx [mm] | cells in the 4 mm layer | pad mass scaling | Courant number | patch radius [mm] | particles | "
                "simulated (held) | substeps / step | "
                "MPM wall / 50 ms step [ms] | second half of the hold: substeps, ms / step | Fn [N] | "
                "Fn spread over hold | error | Fn from pad stress [N] | stress / contact | pressure map × area / contact |",
                "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(curve["runs"], key=lambda r: r["step_ms"]):
        if fem:  # (the stress reading equals the contact force by construction here: not shown)
            out.append(f"| {r['dx'] * 1e3:g} | {r['spacing'] * 1e3:.4g} | {4e-3 / r['spacing']:.0f} | {r['particles']} | "
                       f"{r['step_ms']:.0f} | {r['held_ms']:.0f} | {r['Fn']:.4f} | {_pct(r['err'])} | "
                       f"{_pct(r['F_pressure'] / r['Fn'] - 1)} |")
            continue
        patch = "off" if r["patch_radius"] is None else f"{r['patch_radius'] * 1e3:g}"
        out.append(f"| {r['dx'] * 1e3:g} | {4e-3 / r['dx']:.1f} | {r['mass_scaling']:g} | {r['cfl']:g} | {patch} | "
                   f"{r['particles']} | "
                   f"{r['active']:.0f} | "
                   f"{r['substeps']:.0f} | {r['step_ms']:.0f} | {r['held_substeps']:.0f}, {r['held_ms']:.0f} | "
                   f"{r['Fn']:.4f} | {100 * r['F_spread']:.1f}% | "
                   f"{_pct(r['err'])} | {r['F_stress']:.4f} | {_pct(r['F_stress'] / r['Fn'] - 1)} | "
                   f"{_pct(r['F_pressure'] / r['Fn'] - 1)} |")
    return "\n".join(out)


_PRECOMPUTE = {"auto": None, "on": True, "off": False}  # --fem-precompute


def _solver(args) -> str:
    """The pad solver of the command line, as the tables' headers name it."""
    return f"{args.pad_solver} ({args.fem_model})" if args.pad_solver == "fem" else args.pad_solver


def main(argv: list[str] | None = None) -> int:
    from ..config import SolverSettings

    default_dx, default_ms = SolverSettings().dx, SolverSettings().mass_scaling
    ap = cli("pad", __doc__)
    ap.add_argument("--quick", action="store_true", help="dx 2, 1.5, 1 mm and fewer control steps")
    ap.add_argument("--dx", type=float, nargs="+", help="grid spacings [m] (default: %g, 7.5e-4, 5e-4)" % default_dx)
    ap.add_argument("--depths", type=float, nargs="+", default=[0.5e-3, 1.0e-3], help="press depths [m]")
    ap.add_argument("--thickness", type=float, help="soft layer thickness [m] (default: PadSpec's)")
    ap.add_argument("--indenters", nargs="+", default=["plate", "sphere"], choices=["plate", "sphere"])
    ap.add_argument("--friction", type=float, default=FRICTION)
    arch_option(ap)
    ap.add_argument("--out", default="out/bench_pad")
    ap.add_argument("--curve", action="store_true",
                    help="speed-vs-error curve instead: --dx grids at the default mass scaling, plus the "
                         "--mass-scaling values at the default dx (first --indenters, first --depths)")
    ap.add_argument("--mass-scaling", type=float, nargs="+", default=[250.0, 4000.0, 16000.0],
                    help="pad pseudo-mass factors of the curve at the default dx")
    ap.add_argument("--patch-radius", type=float, nargs="*", default=[],
                    help="active patch radii [m] of the curve, at the default dx with the default mass "
                         "scaling and with x4000")
    ap.add_argument("--cfl", type=float, nargs="*", default=[],
                    help="Courant numbers of extra curve points: every --dx grid at the default mass scaling")
    ap.add_argument("--hold", type=int, default=CURVE.hold,
                    help="held control steps of each curve point (the force is read over the second half)")
    ap.add_argument("--pad-solver", default="mpm", choices=["mpm", "fem"],
                    help="the pad's solver (GaussTacSim's pad_solver; with --curve, --dx points only)")
    ap.add_argument("--fem-model", default="linear", choices=["linear", "neo_hookean"],
                    help="the fem pad's material model (with --pad-solver fem)")
    ap.add_argument("--fem-precompute", default="auto", choices=["auto", "on", "off"],
                    help="the fem pad's compliance among all its surface points up front (on), point by point (off), "
                         "or when it takes at most 256 MiB (auto: dx >= 1 mm)")
    ap.add_argument("--pad-surface", default="mesh", choices=["particles", "mesh"],
                    help="where the indenter touches the pad (GaussTacSim's pad_surface; curve only)")
    args = ap.parse_args(argv)
    if args.curve:
        arch = backend.init(args.arch)
        dxs = args.dx or [2e-3, 1.5e-3, default_dx, 0.75e-3, 0.5e-3]
        points = [(dx, default_ms, None) for dx in dxs]
        if args.pad_solver == "mpm":
            points += [(default_dx, m, None) for m in args.mass_scaling]
            points += [(default_dx, m, r) for r in args.patch_radius for m in sorted({default_ms, 4000.0})]
            points += [(dx, default_ms, None, c) for c in args.cfl for dx in dxs]
        t0 = time.perf_counter()
        curve = speed_curve(points, args.indenters[0], args.depths[-1], pad_surface=args.pad_surface,
                            hold=args.hold, pad_solver=args.pad_solver, fem_model=args.fem_model,
                            fem_precompute=_PRECOMPUTE[args.fem_precompute])
        text = (f"on {arch} ({os.cpu_count()} cores), pad_surface={args.pad_surface}, pad solver {_solver(args)}, "
                f"total {time.perf_counter() - t0:.0f} s\n\n"
                + format_curve(curve, args.indenters[0], args.depths[-1]))
        print(text)
        write_report(args.out, "curve.md", text)
        return 0
    dxs = args.dx or ([2e-3, 1.5e-3, 1e-3] if args.quick else [default_dx, 0.75e-3, 0.5e-3])
    protocol = QUICK if args.quick else FULL
    arch = backend.init(args.arch)
    os.makedirs(args.out, exist_ok=True)
    t0 = time.perf_counter()
    cases = run(dxs, args.indenters, args.depths, args.thickness, protocol, args.friction,
                pad_solver=args.pad_solver, fem_model=args.fem_model, fem_precompute=_PRECOMPUTE[args.fem_precompute])
    ana = analyse(cases, default_dx)
    spec = index_spec(args.thickness)
    head = (f"Index pad convergence on {arch} ({os.cpu_count()} cores): thickness {spec.thickness * 1e3:g} mm, "
            f"E = {spec.material.E / 1e6:g} MPa, nu = {spec.material.nu:g}, friction {args.friction:g}, "
            f"sphere R = {SPHERE_RADIUS * 1e3:g} mm, slide {SLIDE * 1e3:g} mm, protocol {asdict(protocol)}, "
            f"pad solver {_solver(args)} "
            f"(50 ms steps), total {time.perf_counter() - t0:.0f} s")
    text = head + "\n\n" + format_tables(cases, ana, default_dx)
    print(text)
    write_report(args.out, "pad.md", text)
    plain = [{**c, "phases": [{**ph, "maps": {k: v.tolist() for k, v in ph["maps"].items()}} for ph in c["phases"]]}
             for c in cases]
    write_json(args.out, "pad.json", dict(arch=arch, default_dx=default_dx, protocol=asdict(protocol), cases=plain, **ana),
               indent=1)
    images = plot_maps(cases, args.out)
    print(f"\nwrote {args.out}/pad.md, pad.json and {len(images)} map images")
    return 0
