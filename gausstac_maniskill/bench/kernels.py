"""``python -m gausstac_maniskill.bench kernels [--arch cpu|cuda] [--steps N] [--probe] [--ir] [--launches N]``
— where the MPM time goes on the product pad.

The index pad pressed 1 mm by a 5 mm sphere (``bench pad``'s scene); held control steps run under
Taichi's kernel profiler. Prints particles, substeps, wall time, throughput [particle-substeps/s]
and Taichi's per-task table (each parallel loop of ``advance`` and ``prepare``; the rest is launch
overhead); ``--steps N`` also each task's spread over the substeps (min, p10, median, mean, p90).
``--probe`` instead measures the host's noise (:mod:`~gausstac_maniskill.bench.host_probe`);
``--ir`` counts each task's instructions in Taichi's optimized LLVM IR; ``--launches N`` times
the three kernel launch paths (:mod:`~gausstac_maniskill.kernel_launch`) against each other.
"""
from __future__ import annotations

import os
import time

from .. import environment
from .common import cli


def main(argv: list[str] | None = None) -> int:
    ap = cli("kernels", __doc__)
    ap.add_argument("--dx", type=float, default=1e-3, help="grid spacing [m] (default: 1 mm, the product's)")
    ap.add_argument("--indenter", default="sphere", choices=["plate", "sphere"])
    ap.add_argument("--arch", default="cpu", choices=["cpu", "cuda"], help="Taichi backend (default: cpu)")
    ap.add_argument("--launches", type=int, default=0, metavar="N",
                    help="compare the three launch paths over N held steps each (no profiler)")
    ap.add_argument("--steps", type=int, default=1, metavar="N",
                    help="held steps under the profiler (default 1); with N > 1 also each task's spread")
    ap.add_argument("--probe", action="store_true", help="measure the host's noise only (no pad scene)")
    ap.add_argument("--ir", action="store_true", help="also count each task's instructions in the optimized IR")
    args = ap.parse_args(argv)
    if args.steps < 1:
        ap.error(f"--steps {args.steps}: at least 1")
    if args.probe and args.arch != "cpu":
        ap.error("--probe measures the CPU host: use it with --arch cpu")
    if args.launches <= 0 and not args.probe:  # the probe times whole launches: no profiler in them
        environment.write("GAUSSTAC_KERNEL_PROFILER", "1")
    from .. import backend

    arch = backend.init(args.arch)  # raises BackendError if cuda was asked for and does not work
    import taichi as ti

    if args.probe:
        from .host_probe import probe_host

        return probe_host()

    from . import scenes as P

    ir_dir = None
    if args.ir:  # Taichi writes each kernel's optimized IR to the working directory as it compiles it
        import tempfile

        from taichi.lang import impl

        ir_dir, cwd = tempfile.TemporaryDirectory(), os.getcwd()
        cfg = impl.current_cfg()
        cfg.print_kernel_llvm_ir_optimized, cfg.offline_cache = True, False  # compile here, not from the cache
        os.chdir(ir_dir.name)
    try:
        sim, W = P.make_sim(args.dx, args.indenter)

        def step(z: float):
            sim.step({P.INDEX: P.LINK_POSE}, P.DT, {"indenter": P.indenter_pose(args.indenter, W, z)})
            return sim.world.last_step

        for z in (P.GAP, -0.5e-3, -1e-3):  # JIT, then press
            step(z)
    finally:
        if ir_dir is not None:  # back where the user started, whatever happened
            impl.current_cfg().print_kernel_llvm_ir_optimized = False
            os.chdir(cwd)
    if ir_dir is not None:
        print_ir_counts(ir_dir.name)
        ir_dir.cleanup()
    if args.launches > 0:
        return compare_launches(step, args.launches)
    ti.profiler.clear_kernel_profiler_info()
    t0 = time.perf_counter()
    substeps = 0
    for _ in range(args.steps):
        info = step(-1e-3)
        substeps += info.substeps
    wall = time.perf_counter() - t0
    busy = ti.profiler.get_kernel_profiler_total_time()
    n = info.active_particles
    print(f"index pad, {args.indenter} pressed 1 mm, dx = {args.dx * 1e3:g} mm, Taichi {arch}: "
          f"{n} particles, {substeps} substeps in {args.steps} held step(s), {info.grid_cells} grid cells")
    print(f"wall {wall / args.steps * 1e3:.0f} ms per 50 ms step, in kernels {busy / args.steps * 1e3:.0f} ms "
          f"({100 * busy / wall:.0f} %), launch overhead {1e3 * (wall - busy) / substeps:.2f} ms per substep")
    print(f"throughput {n * substeps / wall / 1e6:.2f} M particle-substeps/s "
          f"({n * substeps / busy / 1e6:.2f} M/s in kernels)")
    if args.steps > 1:
        task_spread(n, substeps)
    ti.profiler.print_kernel_profiler_info("count")
    return 0


def task_spread(particles: int, substeps: int) -> None:
    """Print each task of :func:`~gausstac_maniskill.mpm.kernels.prepare` and
    :func:`~gausstac_maniskill.mpm.kernels.advance` over the profiled substeps: min, p10, median,
    mean, p90 [ms] (those under 10 µs at the median only in the sums); then each column's sum over
    all tasks and the throughput it implies [M particle-substeps/s]."""
    import numpy as np
    from taichi.lang import impl

    prog = impl.get_runtime().prog  # every record, not only Taichi's per-kernel summary (its table's source)
    prog.sync_kernel_profiler()
    prog.update_kernel_profiler()
    times: dict[str, list[float]] = {}
    for rec in prog.get_kernel_profiler_records():
        if rec.name.startswith(("advance_", "prepare_")):
            times.setdefault(rec.name, []).append(rec.kernel_time)
    cols = ("min", "p10", "median", "mean", "p90")
    sums = np.zeros(len(cols))
    print(f"each task over {substeps} substeps [ms]:")
    print(f"  {'task':40s}" + "".join(f"{c:>9s}" for c in cols))
    for name, t in sorted(times.items(), key=lambda kv: -float(np.median(kv[1]))):
        a = np.asarray(t)
        row = np.array([a.min(), np.percentile(a, 10), np.median(a), a.mean(), np.percentile(a, 90)])
        sums += row
        if row[2] >= 0.01:
            print(f"  {name:40s}" + "".join(f"{v:9.3f}" for v in row))
    print(f"  {'sum [ms per substep]':40s}" + "".join(f"{v:9.3f}" for v in sums))
    print(f"  {'M particle-substeps/s in kernels':40s}" + "".join(f"{particles / v / 1e3:9.2f}" for v in sums))


def ir_counts(text: str, kernel: str = "advance") -> dict[str, dict[str, int]]:
    """Instruction counts of each parallel task of ``kernel`` in Taichi's optimized LLVM IR ``text``:
    {task: {"all", "load", "store", "float"}}, over the task's own launch code and its loop body (the
    ``function_body`` that follows its definition); "float" counts fadd/fsub/fmul/fdiv/fneg and fused multiply-adds,
    one per vector lane."""
    import re

    counts: dict[str, dict[str, int]] = {}
    task = None
    for line in text.splitlines():
        head = re.match(r"define [^@]*@([\w.]+)\(", line)
        if head:
            name = head.group(1)
            if name.startswith(kernel + "_") and name.endswith("_range_for"):
                task = name
                counts[task] = {"all": 0, "load": 0, "store": 0, "float": 0}
            elif not name.startswith("function_body"):
                task = None  # a runtime function, a serial task: not counted
            continue
        if task is None or not line.startswith("  ") or line.lstrip().startswith(";"):
            continue
        op = re.match(r"\s+(?:%\S+ = )?(\w+)", line)
        if op is None or op.group(1) in ("br", "ret", "phi", "switch", "unreachable"):
            continue  # control flow and SSA joins are not work
        c = counts[task]
        c["all"] += 1
        if op.group(1) in ("load", "store"):
            c[op.group(1)] += 1
        elif re.search(r"\b(fadd|fsub|fmul|fdiv|fneg)\b|@llvm\.fmuladd|@llvm\.fma\b", line):
            lanes = re.search(r"<(\d+) x float>", line)
            c["float"] += int(lanes.group(1)) if lanes else 1
    return counts


def print_ir_counts(folder: str) -> None:
    """Print :func:`ir_counts` of ``advance`` from the IR files Taichi wrote to ``folder``."""
    import glob

    for path in sorted(glob.glob(os.path.join(folder, "*.ll"))):
        with open(path) as f:
            text = f.read()
        if "define void @advance_" in text:
            counts = ir_counts(text)
            print("instructions of each advance task's body in the optimized IR (every branch, unrolled stencils):")
            print(f"  {'task':40s}{'all':>8s}{'load':>8s}{'store':>8s}{'float':>8s}")
            for task, c in counts.items():
                print(f"  {task:40s}" + "".join(f"{c[k]:8d}" for k in ("all", "load", "store", "float")))
            return
    print(f"no IR of advance found in {folder} (was the kernel compiled in this run?)")


#: the launch paths of ``--launches``: (name, kernel_launch.ENABLED, kernel_launch.LEAN_ARGS)
LAUNCH_PATHS = (("planned context (default)", True, True), ("cached, Taichi's arguments", True, False),
                ("Taichi's call", False, True))


def compare_launches(step, n: int) -> int:
    """Time ``step(-1e-3)`` (one held control step) under each of :data:`LAUNCH_PATHS` in turn,
    ``n`` times each; print the medians [ms per substep] and the paired ratios."""
    import statistics
    import time

    from .. import kernel_launch

    per: dict[str, list] = {name: [] for name, _, _ in LAUNCH_PATHS}
    try:
        for _ in range(n):
            for name, enabled, lean in LAUNCH_PATHS:
                kernel_launch.ENABLED, kernel_launch.LEAN_ARGS = enabled, lean
                t0 = time.perf_counter()
                info = step(-1e-3)
                per[name].append((time.perf_counter() - t0) / info.substeps)
    finally:
        kernel_launch.ENABLED, kernel_launch.LEAN_ARGS = True, True
    base = per[LAUNCH_PATHS[0][0]]
    print(f"index pad, sphere pressed 1 mm: {info.active_particles} particles, {n} held steps per launch path")
    for name, times in per.items():
        ratio = statistics.median(t / b for t, b in zip(times, base))
        print(f"  {name:28s} {1e3 * statistics.median(times):7.3f} ms per substep "
              f"({info.active_particles / statistics.median(times) / 1e6:.2f} M particle-substeps/s), "
              f"{ratio:.3f} x the default")
    return 0
