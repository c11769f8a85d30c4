"""Pads solved at equilibrium (:mod:`gausstac_maniskill.fem`): the thin layer against theory, and the product pad.

``python -m gausstac_maniskill.bench quasistatic [--sizes 1e-3 5e-4] [--nu 0.45 0.48 0.499]
[--pad-sizes 1e-3 5e-4] [--depths 2.5e-4 5e-4 1e-3] [--models linear neo_hookean] [--friction 0.5]
[--mpm-dx 1e-3 | --no-mpm] [--no-layer] [--out DIR]``

1. The bonded thin layer of ``bench thinlayer`` pressed by a frictionless paraboloid in
   small-displacement contact (:func:`layer_point`): the force error against the bonded-layer
   solution (:func:`~gausstac_maniskill.reference.layer_force`) per element size, ν and a/h.
2. The index pad pressed by the sphere and the plate of ``bench pad`` to each depth in turn
   (:func:`pad_rows`), per element size and material model: the normal force against the finest
   size, the contact iterations and the solve time per press and held step; with ``--mpm-dx`` the
   explicit MPM's held force on the same pad beside it.
"""
from __future__ import annotations

import math
import os
import time

import numpy as np

from ..reference import layer_force
from .common import arch_option, cli, write_json
from .scenes import (A_OVER_H, E_LAYER, H_LAYER, STRAIN, Protocol, index_pad, indenter_collider, indenter_pose,
                     paraboloid, press_pad)

__all__ = ["layer_point", "layer_table", "pad_rows", "main"]

PAD_DEPTHS = (0.25e-3, 0.5e-3, 1e-3)
PRESS_STEPS = 4  # solves per press increment when there is friction


def layer_point(a_over_h: float, size: float, nu: float, h: float = H_LAYER, E: float = E_LAYER) -> dict:
    """The bonded layer pressed to δ = STRAIN·h by the paraboloid with √(Rδ) = a_over_h·h,
    elements of edge ``size`` [m]; returns the force [N] beside the layer solution's."""
    from ..fem import layer_body

    d = STRAIN * h
    R = (a_over_h * h) ** 2 / d
    a = math.sqrt(R * d)
    t0 = time.perf_counter()
    body = layer_body(h, max(3 * a, a + 4 * h), size, E, nu)
    t1 = time.perf_counter()
    res = body.solve(paraboloid(R, [0.0, 0.0, h - d]))
    t2 = time.perf_counter()
    F = -4.0 * float(res.total_force[2])
    F_layer = layer_force(E, nu, R, d, h)[0]
    return dict(a_over_h=a_over_h, size=size, nu=nu, R=R, d=d, dofs=body.num_free, points=res.candidates,
                F=F, F_layer=F_layer, err=100.0 * (F / F_layer - 1.0), build_s=t1 - t0, solve_s=t2 - t1)


def layer_table(sizes, nus, a_over_h=A_OVER_H, progress: bool = True) -> tuple[str, list[dict]]:
    """Markdown table of :func:`layer_point` over element sizes × ν × a/h, and its rows."""
    from tqdm import tqdm

    rows = []
    with tqdm(total=len(sizes) * len(nus) * len(a_over_h), desc="thin layer", disable=not progress) as bar:
        for nu in nus:
            for size in sizes:
                for r in a_over_h:
                    rows.append(layer_point(r, size, nu))
                    bar.update(1)
    head = "| ν | element [mm] | elements through h | " + " | ".join(f"a/h = {r:g}" for r in a_over_h) + \
           " | max \\|err\\|, a/h ≤ 2 | unknowns | factor [s] | solve [s] |"
    lines = [f"Force error [%] against the layer solution (h = {H_LAYER * 1e3:g} mm, δ = {STRAIN:g} h, frictionless "
             "paraboloid in small-displacement contact)", "", head, "|" + "---|" * (len(a_over_h) + 7)]
    for nu in nus:
        for size in sizes:
            rs = [x for x in rows if x["nu"] == nu and x["size"] == size]
            worst = max(abs(x["err"]) for x in rs if x["a_over_h"] <= 2.0 + 1e-9)
            lines.append(f"| {nu} | {size * 1e3:g} | {H_LAYER / size:.0f} | " +
                         " | ".join(f"{x['err']:+.1f}" for x in rs) +
                         f" | {worst:.1f} | {min(x['dofs'] for x in rs)}–{max(x['dofs'] for x in rs)} | "
                         f"{max(x['build_s'] for x in rs):.1f} | {max(x['solve_s'] for x in rs):.1f} |")
    return "\n".join(lines), rows


def pad_rows(sizes, indenters=("sphere", "plate"), depths=PAD_DEPTHS, models=("linear",), friction: float = 0.0,
             progress: bool = True) -> list[dict]:
    """The index pad pressed by each indenter through ``depths`` in turn (Coulomb ``friction``),
    per element size and material model. A linear body reads the contact at its rest surface, a
    ``neo_hookean`` one at its displaced surface, each depth starting from the last one's state
    (and, with friction, its points' holds on the indenter)."""
    from tqdm import tqdm

    from ..fem import collider_indenter, pad_body

    rows = []
    total = len(sizes) * len(indenters) * len(depths) * len(models)
    with tqdm(total=total, desc="product pad", disable=not progress) as bar:
        for size in sizes:
            pad = index_pad(size)
            S = pad.sensor_frame  # the link frame is the world frame here
            for model in models:
                for kind in indenters:
                    t0 = time.perf_counter()
                    body = pad_body(pad, model=model)
                    build = time.perf_counter() - t0
                    geometry = "rest" if model == "linear" else "deformed"
                    warm, last = None, 0.0
                    for d in depths:
                        # friction depends on the path: the press is solved in PRESS_STEPS increments
                        # (a 1 mm sphere press in one step reads 17 % low, in 4 within 0.1 % of 8)
                        steps = np.linspace(last, d, PRESS_STEPS + 1)[1:] if friction > 0 else [d]
                        times, its = [0.0], [0]
                        for k, z in enumerate(list(steps) + [d]):  # the press to this depth, then a held step
                            sdf = collider_indenter(indenter_collider(kind, indenter_pose(kind, S, -z), friction))
                            t0 = time.perf_counter()
                            res = body.solve(sdf, geometry=geometry, warm=warm, max_iterations=300)
                            held = k == len(steps)
                            if held:
                                times.append(0.0)
                                its.append(0)
                            times[-1] += time.perf_counter() - t0
                            its[-1] += res.iterations
                            warm = res
                        last = d
                        Fn = -float((S[:3, :3].T @ res.total_force)[2])
                        rows.append(dict(size=size, model=model, indenter=kind, d=d, dofs=body.num_free,
                                         surface=body.num_points, points=res.candidates,
                                         columns=body.columns_solved, Fn=Fn, build_s=build,
                                         iterations=its, first_ms=1e3 * times[0], held_ms=1e3 * times[1]))
                        bar.update(1)
    return rows


def mpm_forces(dx: float, indenters, depths, friction: float = 0.0, progress: bool = True) -> dict:
    """The explicit MPM's held force [N] and ms per step on the same pad, by (indenter, depth)."""
    from tqdm import tqdm

    out = {}
    with tqdm(total=len(indenters) * len(depths), desc=f"MPM dx={dx * 1e3:g} mm", disable=not progress) as bar:
        for kind in indenters:
            for d in depths:
                case = press_pad(dx, kind, [d], protocol=Protocol(press=2, slide=0, hold=4), friction=friction)
                out[(kind, d)] = (case["phases"][0]["Fn_end"], case["step_ms"])
                bar.update(1)
    return out


def pad_table(rows: list[dict], mpm: dict | None, mpm_dx: float | None) -> str:
    ref = {}
    for r in rows:  # the finest element size of each model is the reference of each (indenter, depth)
        k = (r["model"], r["indenter"], r["d"])
        if k not in ref or r["size"] < ref[k]["size"]:
            ref[k] = r
    mcols = f" | MPM dx = {mpm_dx * 1e3:g} mm: Fn [N] | ms / step | FEM / MPM" if mpm else ""
    lines = ["| indenter | depth [mm] | model | element [mm] | unknowns | in contact problem | Fn [N] | "
             "vs finest | iterations | press [ms] | held [ms]" + mcols + " |",
             "|" + "---|" * (11 + (3 if mpm else 0))]
    for r in sorted(rows, key=lambda r: (r["indenter"], r["d"], r["model"], -r["size"])):
        f0 = ref[(r["model"], r["indenter"], r["d"])]["Fn"]
        line = (f"| {r['indenter']} | {r['d'] * 1e3:g} | {r['model']} | {r['size'] * 1e3:g} | {r['dofs']} | "
                f"{r['points']} | {r['Fn']:.4f} | {100 * (r['Fn'] / f0 - 1):+.1f} % | "
                f"{r['iterations'][0]} / {r['iterations'][1]} | {r['first_ms']:.0f} | {r['held_ms']:.0f}")
        if mpm:
            Fm, ms = mpm[(r["indenter"], r["d"])]
            line += f" | {Fm:.4f} | {ms:.0f} | {r['Fn'] / Fm:.3f}"
        lines.append(line + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = cli("quasistatic", __doc__)
    ap.add_argument("--sizes", type=float, nargs="+", default=[1e-3, 5e-4], help="thin layer: element edges [m]")
    ap.add_argument("--nu", type=float, nargs="+", default=[0.45, 0.48, 0.499], help="thin layer: Poisson's ratios")
    ap.add_argument("--pad-sizes", type=float, nargs="+", default=[1e-3, 5e-4],
                    help="product pad: element edges [m] (5e-4 is the particle spacing of the MPM's dx = 1 mm)")
    ap.add_argument("--depths", type=float, nargs="+", default=list(PAD_DEPTHS), help="product pad: press depths [m]")
    ap.add_argument("--indenters", nargs="+", default=["sphere", "plate"], choices=["sphere", "plate"])
    ap.add_argument("--models", nargs="+", default=["linear", "neo_hookean"], choices=["linear", "neo_hookean"],
                    help="product pad: material models")
    ap.add_argument("--friction", type=float, default=0.0, help="product pad: Coulomb friction of the indenters")
    ap.add_argument("--mpm-dx", type=float, default=1e-3, help="the explicit MPM's grid spacing beside [m]")
    ap.add_argument("--no-mpm", action="store_true", help="skip the explicit MPM")
    ap.add_argument("--no-layer", action="store_true", help="skip the thin layer")
    ap.add_argument("--out", default="out/bench_quasistatic", help="directory for results.json")
    arch_option(ap)
    args = ap.parse_args(argv)
    from .. import backend

    backend.init(arch=args.arch)  # the colliders' signed distance (and the MPM) run in Taichi
    os.makedirs(args.out, exist_ok=True)
    t0 = time.perf_counter()
    out = {}
    if not args.no_layer:
        table, out["layer"] = layer_table(args.sizes, args.nu)
        print(table, "\n")
    out["pad"] = rows = pad_rows(args.pad_sizes, args.indenters, args.depths, args.models, args.friction)
    mpm = None if args.no_mpm else mpm_forces(args.mpm_dx, args.indenters, args.depths, args.friction)
    print(f"friction {args.friction:g}")
    print(pad_table(rows, mpm, None if args.no_mpm else args.mpm_dx))
    if mpm:
        out["mpm"] = [dict(indenter=k[0], d=k[1], Fn=v[0], step_ms=v[1]) for k, v in mpm.items()]
    write_json(args.out, "results.json", out, indent=1)
    print(f"\n{time.perf_counter() - t0:.0f} s; results in {args.out}/results.json")
    return 0
