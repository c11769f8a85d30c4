"""Cost against pad size and contact area: the baseline of issue 10's point 7.

``python -m gausstac_maniskill.bench patch [--dx 1e-3] [--out DIR]`` (about 2 min on 2 cores)

A square block pad (4 mm soft layer of the product's silicone on one cell of bound
particles, the product's solver settings: :func:`~gausstac_maniskill.cosim.default_hand_settings`)
is pressed 1 mm by a rigid sphere over two 50 ms steps and held one step. Two sweeps:

* pad width 10, 20 and 40 mm under a 5 mm sphere (one contact patch, a ≈ 2.2 mm);
* sphere radius 2.5, 5, 10 and 20 mm on the 40 mm pad (contact radius a = √(Rδ)).

Reported per run: particles, grid cells, substeps, MPM wall time of the held step and
the normal force. Today the whole awake pad is simulated, so the cost follows the pad's
size, not the contact's; point 7 asks for the reverse (one patch costs about the same on
a 20 and a 40 mm pad).
"""
from __future__ import annotations

import os
import time

import numpy as np

from . import arch_option, cli, write_report

THICKNESS = 4e-3  # m, the product pad's soft layer
DEPTH = 1e-3  # m


def run(width: float, radius: float, dx: float) -> dict:
    """Press a sphere of ``radius`` [m] 1 mm into a ``width`` [m] square pad; see the module."""
    from ..cosim import default_hand_settings
    from ..mpm import MPMWorld, Sphere, box_particles
    from ..tactile import allegro_pad_specs
    from ..transforms import make_pose

    s = default_hand_settings(dx=dx)
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
    return dict(width=width, radius=radius, particles=info.active_particles, cells=info.grid_cells,
                substeps=info.substeps, ms=1e3 * info.wall_time, Fn=float(world.collider_wrench(ball)[0][2]),
                a=float(np.sqrt(radius * DEPTH)))


def format_table(rows: list[dict]) -> str:
    out = ["| pad width [mm] | sphere R [mm] | contact radius √(Rδ) [mm] | particles | grid cells | substeps | "
           "MPM ms / held 50 ms step | Fn [N] |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['width'] * 1e3:g} | {r['radius'] * 1e3:g} | {r['a'] * 1e3:.1f} | {r['particles']} | "
                   f"{r['cells']} | {r['substeps']} | {r['ms']:.0f} | {r['Fn']:.3f} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = cli("patch", __doc__)
    ap.add_argument("--dx", type=float, default=1e-3, help="grid spacing [m] (default: 1 mm, the product's)")
    arch_option(ap)
    ap.add_argument("--out", default="out/bench_patch", help="folder for patch.md")
    args = ap.parse_args(argv)
    from tqdm import tqdm

    from .. import backend

    arch = backend.init(args.arch)
    jobs = [(w, 5e-3) for w in (10e-3, 20e-3, 40e-3)] + [(40e-3, r) for r in (2.5e-3, 10e-3, 20e-3)]
    t0 = time.perf_counter()
    run(10e-3, 5e-3, args.dx)  # compile the kernels first (not counted)
    rows = [run(w, r, args.dx) for w, r in tqdm(jobs, desc="pad size / contact area")]
    rows.sort(key=lambda r: (r["width"], r["radius"]))
    text = (f"on {arch} ({os.cpu_count()} cores), dx = {args.dx * 1e3:g} mm, total "
            f"{time.perf_counter() - t0:.0f} s\n\n" + format_table(rows))
    print(text)
    write_report(args.out, "patch.md", text)
    return 0
