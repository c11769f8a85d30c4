"""``python -m gausstac_maniskill.bench motion [--mass-scaling 15.625 ... 4000] [--indenter plate|sphere]
[--mover object|link] [--press-steps 2]`` — what the pads' pseudo-mass does to a force read while the
contact moves.

The index pad (``bench pad``'s scene, dx = 1 mm) is pressed 1 mm, held, slid 2 mm and held, by the
indenter moving (``--mover object``) or by the finger's link (``link``), at each pad pseudo-mass
factor s. Prints the normal force in motion, at the first and the last held step, and the
tangential force in the slide and after it, each against F0, extrapolated to s → 0 by
F(s) = F0 + c·√s through the two smallest factors.
"""
from __future__ import annotations

import math
import time

import numpy as np

from .common import arch_option, cli, write_report

FIELDS = ("Fn_moving", "Fn_first_held", "Fn_held", "Ft_moving", "Ft_held")
LABELS = {"Fn_moving": "Fn, pressing", "Fn_first_held": "Fn, first held step", "Fn_held": "Fn, held",
          "Ft_moving": "Ft, sliding", "Ft_held": "Ft, held after the slide"}


def run(mass_scaling: float, dx: float = 1e-3, indenter: str = "plate", mover: str = "object",
        depth: float = 1e-3, hold: int = 5, press_steps: int = 2) -> dict:
    """One press-hold-slide-hold sequence at pad pseudo-mass factor ``mass_scaling``, the press
    in ``press_steps`` control steps (depth / press_steps each after the first, which also
    closes the 0.2 mm gap); returns ``{"mass_scaling", "substeps", "step_ms", **FIELDS}`` (forces on the
    indenter in N, sensor axes: Fn along -z into the pad, Ft along the slide; "Fn_moving" is
    the press's last step)."""
    from . import scenes as P

    sim, W = P.make_sim(dx, indenter, mass_scaling=mass_scaling)
    R = W[:3, :3]

    def link_at(dz: float, dx_: float = 0.0) -> np.ndarray:
        T = P.LINK_POSE.copy()
        T[:3, 3] += R @ np.array([dx_, 0.0, dz])
        return T

    forces, walls, subs = [], [], []

    def step(z: float, x: float, link_dz: float = 0.0, link_dx: float = 0.0) -> None:
        t0 = time.perf_counter()
        sim.step({P.INDEX: link_at(link_dz, link_dx)}, P.DT, {"indenter": P.indenter_pose(indenter, W, z, x)})
        walls.append(time.perf_counter() - t0)
        subs.append(sim.world.last_step.substeps)
        F = R.T @ sim.object_wrench("indenter")[0]
        forces.append((F[2], -F[0]))

    path = [(-depth * k / press_steps, 0.0) for k in range(1, press_steps + 1)] + [(-depth, 0.0)] * hold \
        + [(-depth, P.SLIDE * k / 2) for k in (1, 2)] + [(-depth, P.SLIDE)] * hold
    if mover == "object":
        step(P.GAP, 0.0)
        for z, x in path:
            step(z, x)
    else:  # the indenter stands at -depth; the link makes the same relative moves (-x: the indenter slides +x)
        for z, x in [(P.GAP, 0.0)] + path:
            step(-depth, 0.0, -depth - z, -x)
    f = np.array(forces[1:])  # one row per step of ``path``
    return dict(mass_scaling=float(mass_scaling), substeps=float(np.mean(subs[1:])),
                step_ms=1e3 * float(np.median(walls[1:])),
                Fn_moving=float(f[press_steps - 1, 0]), Fn_first_held=float(f[press_steps, 0]),
                Fn_held=float(f[press_steps + hold - 1, 0]), Ft_moving=float(f[press_steps + hold + 1, 1]),
                Ft_held=float(f[-1, 1]))


def extrapolate(rows: list[dict]) -> dict:
    """F0 of every field: F(s) = F0 + c·√s through the two smallest mass-scaling factors."""
    a, b = sorted(rows, key=lambda r: r["mass_scaling"])[:2]
    sa, sb = math.sqrt(a["mass_scaling"]), math.sqrt(b["mass_scaling"])
    return {k: a[k] - (b[k] - a[k]) / (sb - sa) * sa for k in FIELDS}


def table(rows: list[dict], f0: dict, title: str) -> str:
    """The printed table: one row per factor, each force with its error against F0."""
    lines = [title, "", "| pad mass scaling | substeps / step | ms / step | "
             + " | ".join(LABELS[k] + " [N]" for k in FIELDS) + " |",
             "|---" * (3 + len(FIELDS)) + "|"]
    for r in sorted(rows, key=lambda r: r["mass_scaling"]):
        cells = [f"{r[k]:.3f} ({100 * (r[k] / f0[k] - 1):+.1f} %)" for k in FIELDS]
        lines.append(f"| {r['mass_scaling']:g} | {r['substeps']:.0f} | {r['step_ms']:.0f} | " + " | ".join(cells) + " |")
    lines.append("| s → 0 (F0) | | | " + " | ".join(f"{f0[k]:.3f}" for k in FIELDS) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = cli("motion", __doc__)
    ap.add_argument("--mass-scaling", type=float, nargs="+", default=[15.625, 62.5, 250.0, 1000.0, 4000.0],
                    help="pad pseudo-mass factors (the two smallest give the extrapolation)")
    ap.add_argument("--dx", type=float, default=1e-3, help="grid spacing [m] (default: 1 mm, the product's)")
    ap.add_argument("--indenter", default="plate", choices=["plate", "sphere"])
    ap.add_argument("--mover", default="object", choices=["object", "link"])
    ap.add_argument("--press-steps", type=int, default=2,
                    help="control steps of the 1 mm press (default 2: 10 mm/s; 6: 3.3 mm/s; 20: 1 mm/s)")
    ap.add_argument("--out", default="out/bench_motion")
    arch_option(ap)
    args = ap.parse_args(argv)
    if len(args.mass_scaling) < 2:
        ap.error("--mass-scaling needs at least two factors (the extrapolation)")
    from .. import backend
    from tqdm import tqdm

    arch = backend.init(args.arch)
    if args.press_steps < 2:
        ap.error("--press-steps must be at least 2 (the first step only reaches the pad)")
    rows = [run(s, args.dx, args.indenter, args.mover, press_steps=args.press_steps)
            for s in tqdm(args.mass_scaling, desc="mass scaling")]
    f0 = extrapolate(rows)
    from .scenes import DT

    speed = 1e3 * 1e-3 / (args.press_steps * DT)  # mm/s in the press's steps after the first
    text = table(rows, f0, f"Index pad, {args.indenter}, the {args.mover} moving, dx = {args.dx * 1e3:g} mm, press "
                 f"in {args.press_steps} steps ({speed:.1f} mm/s), Taichi {arch}: forces against the pads' "
                 "pseudo-mass (errors against s → 0)")
    print(text)
    suffix = "" if args.press_steps == 2 else f"_press{args.press_steps}"
    print("wrote", write_report(args.out, f"motion_{args.indenter}_{args.mover}{suffix}.md", text))
    return 0
