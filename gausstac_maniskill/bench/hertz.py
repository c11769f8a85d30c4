"""Hertz contact: a rigid frictionless sphere pressed into a thick MPM block (R = 5 mm, E = 0.3 MPa, ν = 0.45).

``python -m gausstac_maniskill.bench hertz [--quick] [--dx 1e-3 7.5e-4 ...] [--grid-contact] [--out DIR]``
``python -m gausstac_maniskill.bench hertz --nu 0.3 0.4 0.45 0.48 0.49 0.499 [--plain]``

A quarter block with slip walls (forces ×4), pressed quasi-statically and held at each depth
(:func:`run_case`). Prints the force, contact radius and pressure profile against Hertz (and
Sneddon's force, :mod:`gausstac_maniskill.reference`) with the cost per 10 ms control step, per
grid spacing. ``--nu``: the Poisson-ratio sweep (volumetric locking, F-bar and with ``--plain``
plain MLS-MPM) at d = 1 mm, against Sneddon and the bonded layer of the block's thickness.
"""
from __future__ import annotations

import math
import os
import time

import numpy as np

from .. import backend
from ..reference import hertz_contact_radius, hertz_force, hertz_peak_pressure, hertz_pressure, sneddon
from .common import arch_option, cli, progress_bar, warmup, write_json, write_report
from .scenes import run_point

R_SPHERE = 5e-3
E_PAD = 3e5
NU_PAD = 0.45
DEPTHS = (0.2e-3, 0.5e-3, 0.75e-3, 1.0e-3, 1.25e-3, 1.5e-3)


def run_case(dx: float, depths=DEPTHS, contact: str = "particle", ramp_transits: float = 4.0,
             hold_transits: float = 4.0, progress: bool = True) -> dict:
    """Press the sphere to each depth of ``depths`` [m] at grid spacing ``dx`` [m] (``contact``: MPMWorld's
    contact mode): a block 10·a_max wide and thick (a_max = √(R·d_max)) on two kinematic cells, grid damping
    near critical, the sphere descending over ``ramp_transits`` P-wave crossings per depth and held
    ``hold_transits``; over the second half of each hold the mean force F, contact radius a = √(A/π)
    (A: top-layer particles in contact × h²) and pressure profile p(r), beside Hertz and Sneddon.
    Returns ``{"dx", "h", "particles", "substeps", "wall", "rate", "rows": [...], ...}`` (SI units)."""
    from ..config import Material, SolverSettings
    from ..geometry import Sphere, box_particles
    from ..mpm import MPMWorld
    from ..transforms import make_pose

    material = Material(E=E_PAD, nu=NU_PAD, density=1100.0)
    E_star = material.plane_strain_modulus
    d_max = max(depths)
    a_max = math.sqrt(R_SPHERE * d_max)
    half_w = 5.0 * a_max  # quarter block: half of a 10·a_max wide pad
    thick = 10.0 * a_max
    half_w = math.ceil(half_w / dx) * dx
    base = 2 * dx  # kinematic bottom layer
    thick = math.ceil(thick / dx) * dx
    c = material.wave_speed
    # grid damping about twice the lowest compressive frequency (π/2)·c/H: near-critical
    damping = 2.0 * (math.pi / 2) * c / (thick + base)
    settings = SolverSettings(dx=dx, gravity=(0.0, 0.0, 0.0), max_substeps=1_000_000, cfl=0.4,
                              damping=damping, mass_scaling=1.0)
    h = settings.particle_spacing
    world = MPMWorld(settings, contact=contact)
    world.add_link("ground", np.eye(4))
    pts = box_particles([0.0, 0.0, -thick - base], [half_w, half_w, 0.0], h)
    world.add_group("pad", pts, material, link="ground", kinematic=pts[:, 2] < -thick)
    world.add_slip_wall(0, 0.0, "+")
    world.add_slip_wall(1, 0.0, "+")
    sphere = world.add_collider(Sphere(radius=R_SPHERE, pose=make_pose([0, 0, R_SPHERE]), friction=0.0))

    transit = (thick + base) / c  # one P-wave crossing of the pad [s]
    dt_sub = settings.cfl * dx / c
    dt_ctrl = 8 * dt_sub * 0.999  # 8 substeps per control step
    steps_ramp_per_m = ramp_transits * transit / dt_ctrl / d_max
    n_hold = max(int(hold_transits * transit / dt_ctrl), 8)

    top = pts[:, 2] > -h  # the top particle layer
    r_top = np.linalg.norm(pts[top][:, :2], axis=1)
    rows, wall, substeps = [], 0.0, 0
    depth = 0.0
    bar = progress_bar(len(depths), f"dx={dx * 1e3:.2f} mm", progress)
    for d in depths:
        n_ramp = max(int(math.ceil((d - depth) * steps_ramp_per_m)), 1)
        for k in range(n_ramp):
            z = depth + (d - depth) * (k + 1) / n_ramp
            world.set_collider_pose(sphere, make_pose([0, 0, R_SPHERE - z]))
            info = world.step(dt_ctrl)
            wall += info.wall_time
            substeps += info.substeps
        depth = d
        forces, areas, prof = [], [], []
        for k in range(n_hold):
            info = world.step(dt_ctrl)
            wall += info.wall_time
            substeps += info.substeps
            if k >= n_hold // 2:
                forces.append(4.0 * world.collider_wrench(sphere)[0][2])
                fz = world.contact_forces("pad")[top][:, 2]
                areas.append(4.0 * np.count_nonzero(fz < 0) * h * h)
                prof.append(-fz / (h * h))
        F_sim = float(np.mean(forces))
        a_sim = math.sqrt(float(np.mean(areas)) / math.pi)
        p_sim = np.mean(prof, axis=0)
        F_h = float(hertz_force(E_star, R_SPHERE, d))
        a_h = hertz_contact_radius(R_SPHERE, d)
        p0 = hertz_peak_pressure(F_h, a_h)
        p_h = hertz_pressure(p0, a_h, r_top)
        sel = r_top <= 1.2 * a_h
        rmse = float(np.sqrt(np.mean((p_sim[sel] - p_h[sel]) ** 2)) / p0)
        F_sn, a_sn = sneddon(E_star, R_SPHERE, d)
        rows.append(dict(d=d, F_sim=F_sim, F_hertz=F_h, F_sneddon=F_sn, a_sim=a_sim, a_hertz=a_h,
                         a_sneddon=a_sn, p_rmse=rmse, p0=p0,
                         profile_r=r_top[sel].tolist(), profile_p=p_sim[sel].tolist()))
        bar.update(1)
    bar.close()
    n_part = world.num_particles
    return dict(dx=dx, h=h, contact=contact, particles=n_part, substeps=substeps, wall=wall,
                dt_sub=dt_sub, rate=n_part * substeps / wall, rows=rows,
                pad=dict(half_width=half_w, thickness=thick, R=R_SPHERE, E=E_PAD, nu=NU_PAD))


NU_SWEEP = (0.3, 0.4, 0.45, 0.48, 0.49, 0.499)


def nu_sweep(nus=NU_SWEEP, dx: float = 1e-3, d: float = 1e-3, fbar_modes=(True,), progress: bool = True,
             ramp: float = 6.0, hold: float = 8.0) -> list[dict]:
    """Press the sphere to ``d`` [m] into the thick block at each Poisson ratio in ``nus``,
    for each F-bar mode in ``fbar_modes``; rows of :func:`~gausstac_maniskill.bench.scenes.run_point`
    (a block 10·a thick and 5·a wide, a = √(R·d); the bonded layer of that thickness its reference; forces in N,
    times in s) with ``fbar`` added. ``ramp``/``hold`` are in shear relaxation times 1/ζ."""
    a = math.sqrt(R_SPHERE * d)
    thick = math.ceil(10.0 * a / dx - 1e-9) * dx
    half_w = math.ceil(5.0 * a / dx - 1e-9) * dx
    rows = []
    bar = progress_bar(len(nus) * len(fbar_modes), f"nu sweep dx={dx * 1e3:.2f} mm", progress)
    for fbar in fbar_modes:
        for nu in nus:
            row = run_point(R_SPHERE, d, h=thick, dx=dx, nu=nu, half_width=half_w, fbar=fbar, ramp=ramp, hold=hold)
            row["fbar"] = fbar
            rows.append(row)
            bar.update(1)
    bar.close()
    return rows


def format_nu_sweep(rows: list[dict]) -> str:
    """Markdown table of :func:`nu_sweep`, with the largest |error| against Sneddon per mode."""
    r0 = rows[0]
    lines = [f"Sphere R = {r0['R'] * 1e3:g} mm pressed d = {r0['d'] * 1e3:g} mm (a = {r0['a'] * 1e3:.2f} mm) into a "
             f"bonded block {r0['h'] * 1e3:g} mm thick, {2 * r0['half_width'] * 1e3:g} mm wide, dx = "
             f"{r0['dx'] * 1e3:g} mm; forces in N, errors of F_sim in %", "",
             "| ν | stress | particles | substeps | MPM wall [s] | F_sim | F_Sneddon | err | F_layer(h) | err | "
             "settle |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['nu']:g} | {'F-bar' if r['fbar'] else 'plain'} | {r['particles']} | {r['substeps']} | "
            f"{r['solver_wall']:.1f} | {r['F_sim']:.4f} | {r['F_sneddon']:.4f} | "
            f"{100 * (r['F_sim'] / r['F_sneddon'] - 1):+.1f} | {r['F_layer']:.4f} | "
            f"{100 * (r['F_sim'] / r['F_layer'] - 1):+.1f} | {r['settle']:.0e} |")
    lines.append("")
    for fbar in sorted({r["fbar"] for r in rows}, reverse=True):
        sel = [r for r in rows if r["fbar"] == fbar]
        worst = max(sel, key=lambda r: abs(r["F_sim"] / r["F_sneddon"] - 1))
        lines.append(f"{'F-bar' if fbar else 'plain'}: max |err| against Sneddon "
                     f"{100 * abs(worst['F_sim'] / worst['F_sneddon'] - 1):.1f} % (at ν = {worst['nu']:g}; target 5 %)")
    return "\n".join(lines)


def summarize(case: dict, d_lo: float = 0.5e-3, d_hi: float = 1.5e-3) -> dict:
    """Errors over the depth window [d_lo, d_hi] of one case."""
    rows = [r for r in case["rows"] if d_lo - 1e-12 <= r["d"] <= d_hi + 1e-12]
    f_err = max(abs(r["F_sim"] / r["F_hertz"] - 1) for r in rows)
    a_err = max(abs(r["a_sim"] - r["a_hertz"]) for r in rows)
    p_err = max(r["p_rmse"] for r in rows)
    per_ctrl = case["substeps"] and case["wall"] / case["substeps"]
    ctrl_dt = 0.01
    sub_per_ctrl = math.ceil(ctrl_dt / case["dt_sub"])
    return dict(f_err=f_err, a_err=a_err, a_err_spacings=a_err / case["h"], p_err=p_err,
                sub_per_ctrl=sub_per_ctrl, wall_per_ctrl=per_ctrl * sub_per_ctrl)


def format_tables(cases: list[dict]) -> str:
    lines = ["Speed vs error (errors over d in [0.5, 1.5] mm; control step = 10 ms of simulated time)", "",
             "| contact | dx [mm] | particles | substep [us] | substeps / 10 ms | wall / 10 ms step [s] | "
             "M particle-substeps/s | max F err | max a err [mm] (spacings) | max p RMSE/p0 |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for c in cases:
        s = summarize(c)
        lines.append(
            f"| {c['contact']} | {c['dx'] * 1e3:.2f} | {c['particles']} | {c['dt_sub'] * 1e6:.2f} | "
            f"{s['sub_per_ctrl']} | {s['wall_per_ctrl']:.2f} | {c['rate'] / 1e6:.2f} | "
            f"{100 * s['f_err']:.1f}% | {s['a_err'] * 1e3:.3f} ({s['a_err_spacings']:.2f}) | {s['p_err']:.3f} |")
    lines += ["", "Per depth (F in N, a in mm)", "",
              "| contact | dx [mm] | d [mm] | F sim | F Hertz | F err | F Sneddon | a sim | a Hertz | p RMSE/p0 |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for c in cases:
        for r in c["rows"]:
            lines.append(
                f"| {c['contact']} | {c['dx'] * 1e3:.2f} | {r['d'] * 1e3:.2f} | {r['F_sim']:.4f} | "
                f"{r['F_hertz']:.4f} | {100 * (r['F_sim'] / r['F_hertz'] - 1):+.1f}% | {r['F_sneddon']:.4f} | "
                f"{r['a_sim'] * 1e3:.3f} | {r['a_hertz'] * 1e3:.3f} | {r['p_rmse']:.3f} |")
    return "\n".join(lines)


def plot(cases: list[dict], path: str) -> None:
    """F–d curves (sim vs Hertz) per resolution, and p(r) at the deepest depth."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    dd = np.linspace(0, max(DEPTHS), 100)
    E_star = E_PAD / (1 - NU_PAD ** 2)
    ax1.plot(dd * 1e3, hertz_force(E_star, R_SPHERE, dd), "k-", label="Hertz")
    for c in cases:
        d = [r["d"] * 1e3 for r in c["rows"]]
        ax1.plot(d, [r["F_sim"] for r in c["rows"]], "o--",
                 label=f"MPM {c['contact']} dx={c['dx'] * 1e3:.2f} mm")
    ax1.set_xlabel("indentation d [mm]")
    ax1.set_ylabel("normal force F [N]")
    ax1.set_title(f"Sphere R={R_SPHERE * 1e3:.0f} mm on E={E_PAD / 1e6:.1f} MPa, ν={NU_PAD}")
    ax1.legend(fontsize=8)
    last = cases[-1]["rows"][-1]
    a = last["a_hertz"]
    rr = np.linspace(0, 1.2 * a, 100)
    ax2.plot(rr * 1e3, hertz_pressure(last["p0"], a, rr) / 1e3, "k-", label="Hertz")
    for c in cases:
        r = c["rows"][-1]
        ax2.plot(np.array(r["profile_r"]) * 1e3, np.array(r["profile_p"]) / 1e3, ".", ms=3,
                 label=f"{c['contact']} dx={c['dx'] * 1e3:.2f} mm")
    ax2.set_xlabel("radius r [mm]")
    ax2.set_ylabel("contact pressure p [kPa]")
    ax2.set_title(f"pressure at d={last['d'] * 1e3:.2f} mm")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = cli("hertz", __doc__)
    ap.add_argument("--quick", action="store_true", help="one coarse resolution (about a minute)")
    ap.add_argument("--dx", type=float, nargs="+", help="grid spacings [m] to sweep")
    ap.add_argument("--grid-contact", action="store_true",
                    help="also run the coarsest dx with grid-node contact, for comparison")
    arch_option(ap)
    ap.add_argument("--out", default="out/hertz", help="folder for hertz.png, hertz.md, hertz.json")
    ap.add_argument("--nu", type=float, nargs="+", metavar="NU",
                    help="Poisson-ratio sweep (volumetric locking) at the first --dx (default 1 mm) instead")
    ap.add_argument("--plain", action="store_true", help="with --nu: also run plain MLS-MPM (no F-bar)")
    args = ap.parse_args(argv)
    arch = backend.init(args.arch)
    if args.nu:
        t0 = time.time()
        rows = nu_sweep(args.nu, dx=(args.dx or [1e-3])[0], fbar_modes=(True, False) if args.plain else (True,))
        table = format_nu_sweep(rows)
        print(f"Poisson-ratio sweep on {arch} ({os.cpu_count()} cores), {time.time() - t0:.0f} s\n\n{table}")
        write_report(args.out, "nu_sweep.md", table)
        return 0
    dxs = args.dx or ([1.0e-3] if args.quick else [1.0e-3, 0.75e-3, 0.5e-3])
    os.makedirs(args.out, exist_ok=True)
    print(f"Hertz benchmark on {arch} ({os.cpu_count()} cores): R={R_SPHERE * 1e3} mm, E={E_PAD:g} Pa, "
          f"nu={NU_PAD}, depths {[round(d * 1e3, 2) for d in DEPTHS]} mm")
    cases = []
    t0 = time.time()
    warmup("particle")
    if args.grid_contact:
        warmup("grid")
    print(f"  kernels compiled in {time.time() - t0:.1f} s (not counted below)")
    for dx in dxs:
        cases.append(run_case(dx))
        print(f"  dx={dx * 1e3:.2f} mm: {cases[-1]['particles']} particles, {cases[-1]['wall']:.1f} s, "
              f"{cases[-1]['rate'] / 1e6:.2f} M particle-substeps/s")
    if args.grid_contact:
        cases.append(run_case(max(dxs), contact="grid"))
    table = format_tables(cases)
    print()
    print(table)
    write_report(args.out, "hertz.md", table)
    write_json(args.out, "hertz.json", cases)
    plot(cases, os.path.join(args.out, "hertz.png"))
    print(f"\nwrote {args.out}/hertz.png, hertz.md, hertz.json  (total {time.time() - t0:.0f} s)")
    return 0
