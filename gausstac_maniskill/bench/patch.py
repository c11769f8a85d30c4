"""Cost against pad size and contact area, with and without the active patch (issue 10, point 7).

``python -m gausstac_maniskill.bench patch [--dx 1e-3] [--patch-radius 4e-3 6e-3] [--out DIR]``
(about 3 min on 2 cores)

A square block pad (4 mm soft layer of the product's silicone on one cell of bound
particles, the product's solver settings: :func:`~gausstac_maniskill.cosim.default_hand_settings`)
is pressed 1 mm by a rigid sphere over two 50 ms steps and held one step. Two sweeps:

* pad width 10, 20 and 40 mm under a 5 mm sphere (one contact patch, a ≈ 2.2 mm);
* sphere radius 2.5, 5, 10 and 20 mm on the 40 mm pad (contact radius a = √(Rδ)).

Each case runs on the whole pad and with ``SolverSettings.patch_radius`` set
(:mod:`gausstac_maniskill.mpm.patch`: only the pad within that distance of the contact is
simulated, the rest rides with the link). Reported per run: particles, those simulated in
the held step, grid cells, substeps, MPM wall time of the held step, the normal force and,
for the patch, its error against the whole pad of the same case (what clamping the layer
at the patch's edge costs).
"""
from __future__ import annotations

import os
import time

import numpy as np

from . import arch_option, cli, write_report

THICKNESS = 4e-3  # m, the product pad's soft layer
DEPTH = 1e-3  # m


def run(width: float, radius: float, dx: float, patch: float | None = None) -> dict:
    """Press a sphere of ``radius`` [m] 1 mm into a ``width`` [m] square pad, with the active
    patch ``patch`` [m] (None: the whole pad); see the module."""
    from ..cosim import default_hand_settings
    from ..mpm import MPMWorld, Sphere, box_particles
    from ..tactile import allegro_pad_specs
    from ..transforms import make_pose

    s = default_hand_settings(dx=dx, patch_radius=patch)
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


def main(argv: list[str] | None = None) -> int:
    ap = cli("patch", __doc__)
    ap.add_argument("--dx", type=float, default=1e-3, help="grid spacing [m] (default: 1 mm, the product's)")
    ap.add_argument("--patch-radius", type=float, nargs="*", default=[4e-3, 6e-3],
                    help="active patch radii [m] to run beside the whole pad (default: 1 and 1.5 layers)")
    arch_option(ap)
    ap.add_argument("--out", default="out/bench_patch", help="folder for patch.md")
    args = ap.parse_args(argv)
    from tqdm import tqdm

    from .. import backend

    arch = backend.init(args.arch)
    cases = [(w, 5e-3) for w in (10e-3, 20e-3, 40e-3)] + [(40e-3, r) for r in (2.5e-3, 10e-3, 20e-3)]
    jobs = [(w, r, p) for w, r in cases for p in [None, *args.patch_radius]]
    t0 = time.perf_counter()
    run(10e-3, 5e-3, args.dx, 4e-3)  # compile the kernels first (not counted)
    rows = [run(w, r, args.dx, p) for w, r, p in tqdm(jobs, desc="pad size / contact area / patch")]
    rows.sort(key=lambda r: (r["width"], r["radius"], r["patch"] or 0.0))
    text = (f"on {arch} ({os.cpu_count()} cores), dx = {args.dx * 1e3:g} mm, total "
            f"{time.perf_counter() - t0:.0f} s\n\n" + format_table(rows))
    print(text)
    write_report(args.out, "patch.md", text)
    return 0
