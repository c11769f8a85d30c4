"""Hand benchmarks on the Allegro fingertip pads: ``python -m gausstac_maniskill.bench hand [--quick] [--out DIR]``.

1. Step cost against the number of pads in contact (0–4): a flat plate pressed 1 mm into k of
   the four fingertip pads; wall time per 50 ms control step (idle pads sleep).
2. The index pad pressed along its axis by a rigid plate, against Hertz's half-space estimate
   with the tip's local radius (a sphere fitted to the cap of its collision mesh), at two layer
   thicknesses and three grid spacings, with the wall time per control step.
"""
from __future__ import annotations

import math
import os
import time

import numpy as np

from .. import backend
from .common import arch_option, cli, write_report

INDEX = "link_3.0_tip"


def _hand_poses():
    from ..pose import MujocoPoseSource
    from ..tactile import ALLEGRO_TIPS

    src = MujocoPoseSource()
    return dict(zip(ALLEGRO_TIPS, src.link_poses(list(ALLEGRO_TIPS))[0].numpy()))


def _plate_pose(sim, poses, pad, gap):
    from ..transforms import make_pose

    W = poses[sim.pads[pad].spec.link] @ sim.pads[pad].sensor_frame
    return make_pose(W[:3, 3] + W[:3, 2] * (0.004 + gap), W[:3, :3])


def pads_in_contact(dx: float = 1.5e-3, repeats: int = 4) -> list[dict]:
    """Wall time per 50 ms step with k = 0..4 pads pressed by a plate each."""
    from ..config import SolverSettings
    from ..cosim import GaussTacSim
    from ..geometry import Box
    from ..tactile import allegro_pad_specs

    poses = _hand_poses()
    rows = []
    for k in range(5):
        sim = GaussTacSim(allegro_pad_specs(), poses, settings=SolverSettings(dx=dx), pad_solver="mpm")
        touched = list(sim.pads)[:k]
        for i, name in enumerate(sim.pads):
            # every pad gets a plate; untouched ones keep it 5 cm away (they sleep)
            gap = -1e-3 if name in touched else 0.05
            sim.add_rigid_object(f"plate{i}", Box(half_extents=(0.012, 0.012, 0.004),
                                                  pose=_plate_pose(sim, poses, name, gap), friction=0.5))
        for _ in range(3):  # settle the press (and JIT)
            sim.step(poses, 0.05)
        t0 = time.perf_counter()
        for _ in range(repeats):
            sim.step(poses, 0.05)
        dt = (time.perf_counter() - t0) / repeats
        rows.append(dict(pads_in_contact=k, awake=sum(sim.is_awake(n) for n in sim.pads),
                         particles=sim.world.last_step.active_particles,
                         substeps=sim.world.last_step.substeps, step_s=dt))
    return rows


def tip_radius(pad_link: str = INDEX) -> float:
    """Radius [m] of a sphere fitted (least squares) to the pad cap of the tip's collision mesh."""
    from ..urdf import default_hand_urdf, link_mesh

    mesh = link_mesh(default_hand_urdf(), pad_link)
    v = mesh.vertices[mesh.vertices[:, 0] > 0.6 * mesh.vertices[:, 0].max()]  # palmar cap (+x)
    A = np.c_[2 * v, np.ones(len(v))]
    sol, *_ = np.linalg.lstsq(A, (v ** 2).sum(1), rcond=None)
    c = sol[:3]
    return float(np.sqrt(sol[3] + c @ c))


def press_vs_hertz(dx: float, thickness: float, depths=(0.25e-3, 0.5e-3, 0.75e-3), steps: int = 8) -> dict:
    """Press a flat plate into the index pad; returns force vs depth and timing."""
    from ..config import PadSpec
    from ..config import SolverSettings
    from ..cosim import GaussTacSim
    from ..geometry import Box

    poses = _hand_poses()
    spec = PadSpec(link=INDEX, thickness=thickness, cone_deg=70.0)
    sim = GaussTacSim([spec], {INDEX: poses[INDEX]}, settings=SolverSettings(dx=dx), pad_solver="mpm")
    plate = Box(half_extents=(0.015, 0.015, 0.004), pose=_plate_pose(sim, poses, INDEX, 0.5e-3), friction=0.0)
    sim.add_rigid_object("plate", plate)
    sim.step(poses, 0.05)  # JIT + settle
    E_star = spec.material.plane_strain_modulus
    R = tip_radius()
    rows, wall, n = [], 0.0, 0
    d_prev = 0.0
    for d in depths:
        for k in range(steps):
            z = d_prev + (d - d_prev) * min(1.0, (k + 1) / (steps // 2))
            t0 = time.perf_counter()
            sim.step(poses, 0.05, {"plate": _plate_pose(sim, poses, INDEX, -z)})
            wall += time.perf_counter() - t0
            n += 1
        d_prev = d
        F = float(sim.object_wrench("plate")[0] @ (poses[INDEX] @ sim.pads[INDEX].sensor_frame)[:3, 2])
        F_h = 4.0 / 3.0 * E_star * math.sqrt(R) * d ** 1.5
        rows.append(dict(d=d, F=F, F_hertz=F_h, a_hertz=math.sqrt(R * d),
                         F_map=sim.pad_normal_force(INDEX), F_stress=sim.pad_pressure_force(INDEX)))
    return dict(dx=dx, thickness=thickness, R_tip=R, particles=sim.world.num_particles,
                substeps=sim.world.last_step.substeps, step_s=wall / n, rows=rows)


def main(argv: list[str] | None = None) -> int:
    ap = cli("hand", __doc__)
    ap.add_argument("--quick", action="store_true", help="one spacing, one thickness")
    arch_option(ap)
    ap.add_argument("--out", default="out/bench_hand")
    args = ap.parse_args(argv)
    arch = backend.init(args.arch)
    os.makedirs(args.out, exist_ok=True)
    lines = [f"Hand benchmarks on {arch} ({os.cpu_count()} cores), control step 50 ms, mass scaling 1000", ""]
    rows = pads_in_contact(dx=2e-3 if args.quick else 1.5e-3)
    active1 = next(r["step_s"] for r in rows if r["pads_in_contact"] == 1)
    lines += ["Step cost vs pads in contact (dx = %.1f mm)" % (2.0 if args.quick else 1.5), "",
              "| pads in contact | awake pads | simulated particles | substeps | wall / step [ms] | vs 1 active pad |",
              "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['pads_in_contact']} | {r['awake']} | {r['particles']} | {r['substeps']} | "
                     f"{1e3 * r['step_s']:.1f} | {100 * r['step_s'] / active1:.1f}% |")
    print("\n".join(lines))
    cases = []
    grid = [(2e-3, 2e-3)] if args.quick else [(2e-3, 2e-3), (1.5e-3, 2e-3), (1e-3, 2e-3), (1.5e-3, 4e-3)]
    for dx, th in grid:
        cases.append(press_vs_hertz(dx, th))
    R = cases[0]["R_tip"]
    press = ["", f"Fingertip press (flat plate on the index pad, tip radius fitted R = {R * 1e3:.2f} mm, "
             "E = 0.3 MPa, nu = 0.45): force vs Hertz half-space estimate", "",
             "| dx [mm] | pad thickness [mm] | particles | substeps | wall / step [ms] | d [mm] | a_Hertz [mm] | "
             "F sim [N] | F Hertz [N] | F sim / F Hertz | force map sum [N] | stress estimate [N] |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in cases:
        for r in c["rows"]:
            press.append(f"| {c['dx'] * 1e3:.1f} | {c['thickness'] * 1e3:.1f} | {c['particles']} | {c['substeps']} | "
                         f"{1e3 * c['step_s']:.0f} | {r['d'] * 1e3:.2f} | {r['a_hertz'] * 1e3:.2f} | {r['F']:.3f} | "
                         f"{r['F_hertz']:.3f} | {r['F'] / r['F_hertz']:.2f} | {r['F_map']:.3f} | {r['F_stress']:.3f} |")
    print("\n".join(press))
    write_report(args.out, "hand.md", "\n".join(lines + press))
    print(f"\nwrote {args.out}/hand.md")
    return 0
