"""``python -m gausstac_maniskill.bench compile [--rounds 3] [--steps 5]`` — what Taichi's compiler
settings cost and save.

Each build of ``GAUSSTAC_COMPILE`` (``taichi``: Taichi's defaults; ``product``, unset: Taichi's CFG
pass off; ``fast``: also ``opt_level=0``) runs the index pad pressed 1 mm by a 5 mm sphere in a child
process with an offline cache of its own, empty in the first round. Prints per build the first
control step [s] (every kernel compiled, then run), the median held step [ms], its ratio to the
product build's, and the largest difference of the pad's particle positions from the product
build's [nm].
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .. import environment
from .common import cli

BUILDS = ("taichi", "product", "fast")


def _child(build_dir: Path, steps: int) -> None:
    """Run the scene; write ``times.json`` (first, held) and ``x.npy`` (pad positions) to build_dir."""
    from .. import backend

    backend.init("cpu")
    from . import scenes as P

    sim, W = P.make_sim(1e-3, "sphere")

    def step(z: float) -> None:
        sim.step({P.INDEX: P.LINK_POSE}, P.DT, {"indenter": P.indenter_pose("sphere", W, z)})

    t0 = time.perf_counter()
    step(-0.5e-3)
    first = time.perf_counter() - t0
    step(-1e-3)
    t0 = time.perf_counter()
    for _ in range(steps):
        step(-1e-3)
    held = (time.perf_counter() - t0) / steps
    np.save(build_dir / "x.npy", sim.pad_particles(P.INDEX)[0])
    (build_dir / "times.json").write_text(json.dumps({"first": first, "held": held}))


def _run(build: str, build_dir: Path, steps: int) -> dict:
    env = environment.child_environ(GAUSSTAC_COMPILE="" if build == "product" else build,
                                    TI_OFFLINE_CACHE_FILE_PATH=str(build_dir / "ticache"))
    out = subprocess.run([sys.executable, "-m", "gausstac_maniskill.bench", "compile", "--child", str(build_dir),
                          "--steps", str(steps)], env=env, capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"bench compile: the {build!r} build failed:\n{out.stderr[-2000:]}")
    return json.loads((build_dir / "times.json").read_text())


def main(argv: list[str] | None = None) -> int:
    ap = cli("compile", __doc__)
    ap.add_argument("--rounds", type=int, default=3, help="rounds over the builds (the first compiles)")
    ap.add_argument("--steps", type=int, default=5, help="held steps timed per round")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        _child(Path(args.child), args.steps)
        return 0
    from tqdm import tqdm

    with tempfile.TemporaryDirectory(prefix="gausstac_compile_") as tmp:
        dirs = {b: Path(tmp) / b for b in BUILDS}
        for d in dirs.values():
            d.mkdir()
        first, held = {}, {b: [] for b in BUILDS}
        with tqdm(total=args.rounds * len(BUILDS), desc="bench compile", unit="run") as bar:
            for r in range(args.rounds):  # builds alternate: a slow spell of the machine hits them alike
                for b in BUILDS:
                    t = _run(b, dirs[b], args.steps)
                    first.setdefault(b, t["first"])
                    held[b].append(t["held"])
                    bar.update()
        x = {b: np.load(dirs[b] / "x.npy") for b in BUILDS}
    med = {b: float(np.median(held[b])) for b in BUILDS}
    print(f"index pad, 5 mm sphere pressed 1 mm, dx = 1 mm, Taichi cpu; {args.rounds} rounds of "
          f"{args.steps} held steps")
    print("| build | first step [s] | step [ms] | step / product | max abs dx [nm] |")
    print("|---|---|---|---|---|")
    for b in BUILDS:
        dx = float(np.abs(x[b].astype(np.float64) - x["product"]).max()) * 1e9
        print(f"| {b} | {first[b]:.1f} | {med[b] * 1e3:.0f} | {med[b] / med['product']:.2f} | {dx:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
