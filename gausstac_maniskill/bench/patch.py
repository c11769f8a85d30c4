"""``python -m gausstac_maniskill.bench patch [--pad-solver mpm|fem] [--dx 1e-3] [--patch-radius 4e-3 6e-3]
[--out DIR]``
— cost against pad size and contact area, with and without the active patch.

A square block pad (4 mm layer of the product's silicone) pressed 1 mm by a rigid sphere and held:
pad widths 10, 20, 40 mm under a 5 mm sphere, and sphere radii 2.5–20 mm on the 40 mm pad. MPM:
each case on the whole pad and with ``SolverSettings.patch_radius``; prints particles, those
simulated, grid cells, substeps, MPM wall time of the held step, the normal force and the patch's
error against the whole pad. ``fem``: the pads solved at equilibrium, compliance point by point
and from the full compliance W; prints the one-time cost and memory, each step's wall time, the
loaded points and the normal force (both rows of a case read the same force).
"""
from __future__ import annotations

import os
import time

import numpy as np

from .common import arch_option, cli, write_report

THICKNESS = 4e-3  # m, the product pad's soft layer
DEPTH = 1e-3  # m


def run(width: float, radius: float, dx: float, patch: float | None = None) -> dict:
    """Press a sphere of ``radius`` [m] 1 mm into a ``width`` [m] square pad, with the active
    patch ``patch`` [m] (None: the whole pad); see the module."""
    from ..config import SolverSettings
    from ..geometry import Sphere, box_particles
    from ..mpm import MPMWorld
    from ..tactile import allegro_pad_specs
    from ..transforms import make_pose

    s = SolverSettings(dx=dx, patch_radius=patch)
    world = MPMWorld(s)
    world.add_link("base", np.eye(4))
    pts = box_particles([-width / 2, -width / 2, -THICKNESS - dx], [width / 2, width / 2, 0.0], s.particle_spacing)
    material = allegro_pad_specs()[0].material
    world.add_group("pad", pts, material, link="base", kinematic=pts[:, 2] < -THICKNESS)
    ball = world.add_collider(Sphere(radius=radius, pose=make_pose([0, 0, radius + 0.2e-3]), friction=0.0))
    for k in range(2):
        world.set_collider_pose(ball, make_pose([0, 0, radius - DEPTH * (k + 1) / 2]))
        world.step(0.05)
    info = world.step(0.05)
    return dict(width=width, radius=radius, patch=patch, particles=world.num_particles,
                active=info.active_particles, cells=info.grid_cells,
                substeps=info.substeps, ms=1e3 * info.wall_time, Fn=float(world.collider_wrench(ball)[0][2]),
                a=float(np.sqrt(radius * DEPTH)))


def fem_pad(width: float, dx: float, full: bool) -> dict:
    """A ``width`` [m] square block pad solved at equilibrium (elements of the particle spacing
    at grid ``dx`` [m]), its compliance among all surface points computed now (``full``; not
    cached on disk, so that its cost is measured) or left to be solved point by point."""
    from ..config import SolverSettings
    from ..fem import layer_body
    from ..fem.compliance import estimated_bytes
    from ..tactile import allegro_pad_specs

    size = SolverSettings(dx=dx).particle_spacing
    material = allegro_pad_specs()[0].material
    t0 = time.perf_counter()
    body = layer_body(THICKNESS, width / 2, size, material.E, material.nu, quarter=False)
    if full:
        body.precompute_compliance(progress=True, cache=False)
        memory = estimated_bytes(body.num_points)
    else:
        lu = body._lu
        memory = (lu.L.nnz + lu.U.nnz) * 12  # float64 values and int32 indices
    return dict(body=body, width=width, full=full, once=time.perf_counter() - t0, memory=memory)


def run_fem(pad: dict, radius: float) -> dict:
    """Press a sphere of ``radius`` [m] 1 mm into ``pad`` (:func:`fem_pad`); see the module."""
    from ..fem import Indenter

    body = pad["body"]
    columns = body.columns_solved

    def sphere(q):
        r = np.linalg.norm(q, axis=1)
        return r - radius, q / np.maximum(r, 1e-12)[:, None]

    res, ms = None, []
    for depth in (DEPTH / 2, DEPTH, DEPTH):  # two press steps, then held
        pose = np.eye(4)
        pose[2, 3] = THICKNESS + radius - depth
        t = time.perf_counter()
        res = body.solve(Indenter(sphere, pose), geometry="deformed", margin=0.0, warm=res)  # as the pads
        ms.append(1e3 * (time.perf_counter() - t))
    return dict(width=pad["width"], radius=radius, full=pad["full"], elements=len(body.body.voxels),
                points=body.num_points, once=pad["once"], memory=pad["memory"], press_ms=ms[:2], held_ms=ms[2],
                loaded=int((np.abs(res.force).sum(1) > 0).sum()), columns=body.columns_solved - columns,
                Fn=float(-res.total_force[2]), a=float(np.sqrt(radius * DEPTH)))


def format_fem_table(rows: list[dict]) -> str:
    """Markdown table of :func:`run_fem` rows."""
    out = ["| pad width [mm] | sphere R [mm] | contact radius √(Rδ) [mm] | elements | surface points | compliance | "
           "one-time [s] | memory held [MB] | press steps [ms] | held step [ms] | loaded points | Fn [N] |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        how = "all points (W)" if r["full"] else f"point by point ({r['columns']} columns)"
        once = f"{r['once']:.1f}" if r["once"] is not None else "(as above)"
        out.append(f"| {r['width'] * 1e3:g} | {r['radius'] * 1e3:g} | {r['a'] * 1e3:.1f} | {r['elements']} | "
                   f"{r['points']} | {how} | {once} | {r['memory'] / 1e6:.0f} | "
                   f"{', '.join(f'{m:.0f}' for m in r['press_ms'])} | {r['held_ms']:.1f} | {r['loaded']} | "
                   f"{r['Fn']:.4f} |")
    return "\n".join(out)


def format_table(rows: list[dict]) -> str:
    """Markdown table; each patch row's error is against the whole-pad row of its case."""
    whole = {(r["width"], r["radius"]): r["Fn"] for r in rows if r["patch"] is None}
    out = ["| pad width [mm] | sphere R [mm] | contact radius √(Rδ) [mm] | patch radius [mm] | particles | "
           "simulated | grid cells | substeps | MPM ms / held 50 ms step | Fn [N] | Fn vs whole pad |",
           "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ref = whole.get((r["width"], r["radius"]))
        err = "" if r["patch"] is None or ref is None else f"{100 * (r['Fn'] / ref - 1):+.1f}%"
        patch = "whole pad" if r["patch"] is None else f"{r['patch'] * 1e3:g}"
        out.append(f"| {r['width'] * 1e3:g} | {r['radius'] * 1e3:g} | {r['a'] * 1e3:.1f} | {patch} | "
                   f"{r['particles']} | {r['active']} | {r['cells']} | {r['substeps']} | {r['ms']:.0f} | "
                   f"{r['Fn']:.3f} | {err} |")
    return "\n".join(out)


CASES = [(w, 5e-3) for w in (10e-3, 20e-3, 40e-3)] + [(40e-3, r) for r in (2.5e-3, 10e-3, 20e-3)]


def main(argv: list[str] | None = None) -> int:
    ap = cli("patch", __doc__)
    ap.add_argument("--pad-solver", choices=("mpm", "fem"), default="mpm",
                    help="the explicit MPM pads with and without the active patch (default), "
                         "or the pads at equilibrium")
    ap.add_argument("--dx", type=float, default=1e-3, help="grid spacing [m] (default: 1 mm, the product's)")
    ap.add_argument("--patch-radius", type=float, nargs="*", default=[4e-3, 6e-3],
                    help="active patch radii [m] to run beside the whole pad (default: 1 and 1.5 layers; MPM only)")
    ap.add_argument("--fem-w-max", type=float, default=256.0,
                    help="fem: also run with the full compliance where it takes at most this many MiB "
                         "(default 256, the pads' own limit)")
    arch_option(ap)
    ap.add_argument("--out", default="out/bench_patch", help="folder for patch.md")
    args = ap.parse_args(argv)
    from tqdm import tqdm

    from .. import backend

    arch = backend.init(args.arch)
    t0 = time.perf_counter()
    if args.pad_solver == "fem":
        from ..config import SolverSettings
        from ..fem.compliance import estimated_bytes

        size = SolverSettings(dx=args.dx).particle_spacing
        limit = args.fem_w_max * 2 ** 20
        jobs = [(w, r, full) for w, r in CASES for full in (False, True)
                if not full or estimated_bytes(round(w / size) ** 2) <= limit]
        run_fem(fem_pad(4e-3, 2e-3, False), 2e-3)  # compile the colliders' distance kernel first (not counted)
        rows, shared = [], {}  # one W per pad width: its one-time cost on the first row only
        for w, r, full in tqdm(jobs, desc="pad size / contact area"):
            pad = shared.get(w) if full else None
            if pad is None:
                pad = fem_pad(w, args.dx, full)
                if full:
                    shared[w] = pad
            rows.append(run_fem(pad, r))
            pad["once"] = None  # the next row of this W pays nothing more
        rows.sort(key=lambda r: (r["full"], r["width"]))  # stable: a W pad's first row stays first
        table = format_fem_table(rows)
    else:
        jobs = [(w, r, p) for w, r in CASES for p in [None, *args.patch_radius]]
        run(10e-3, 5e-3, args.dx, 4e-3)  # compile the kernels first (not counted)
        rows = [run(w, r, args.dx, p) for w, r, p in tqdm(jobs, desc="pad size / contact area / patch")]
        rows.sort(key=lambda r: (r["width"], r["radius"], r["patch"] or 0.0))
        table = format_table(rows)
    text = (f"{args.pad_solver} pads on {arch} ({os.cpu_count()} cores), dx = {args.dx * 1e3:g} mm, total "
            f"{time.perf_counter() - t0:.0f} s\n\n" + table)
    print(text)
    write_report(args.out, "patch.md", text)
    return 0
