"""How noisy is this host? (``python -m gausstac_maniskill.bench kernels --probe``)

Four small Taichi kernels take turns: a dependent chain of square roots (arithmetic only), a
read-modify-write sweep over 16 KB (in L1) and over 1 MB (in L2), each on one thread, and the
1 MB sweep on both threads at once (1 MB each, the way the MPM's loops share out their work).
On a host whose cores are shared with another tenant's work, the sweeps' median lies well
above their minimum while the chain's does not: the load/store side is what is shared. The
two-thread sweep waits for the slower thread, as the MPM's loops do: where its median/min is
above the one-thread sweep's, one core was slower than the other. (No ``from __future__ import
annotations`` here: Taichi reads the kernels' annotations as objects.)
"""
import statistics
import time

import numpy as np
import taichi as ti


def probe_host(rounds: int = 200) -> int:
    """Print min, median, p90 [ms] and median/min of three serial kernels taking turns ``rounds``
    times (module docstring). Taichi must be initialised."""
    @ti.kernel
    def chain(a: ti.types.ndarray(), n: ti.i32):
        ti.loop_config(serialize=True)
        for _ in range(1):
            x, y = a[0], a[1]
            for _k in range(n):
                x = ti.sqrt(x * y + 1.0)  # each step waits for the last: the arithmetic units only
            a[2] = x

    @ti.kernel
    def sweep(b: ti.types.ndarray(), reps: ti.i32):
        ti.loop_config(serialize=True)
        for _ in range(1):
            for _k in range(reps):
                for i in range(b.shape[0]):
                    b[i] = b[i] * 0.5 + 1.0  # one load and one store per float

    @ti.kernel
    def sweep_both(b: ti.types.ndarray(), reps: ti.i32):
        ti.loop_config(block_dim=512)  # Taichi's smallest CPU block: one half per thread
        for q in range(2 * 512):
            if q % 512 == 0:
                half = b.shape[0] // 2
                for _k in range(reps):
                    for i in range(q // 512 * half, (q // 512 + 1) * half):
                        b[i] = b[i] * 0.5 + 1.0

    a = ti.ndarray(ti.f32, 16)
    a.from_numpy(np.ones(16, np.float32))
    cases = (("dependent sqrt chain (arithmetic)", chain, (a, 200_000)),
             ("sweep over 16 KB x 1280 (L1)", sweep, (ti.ndarray(ti.f32, 1 << 12), 1280)),
             ("sweep over 1 MB x 20 (L2)", sweep, (ti.ndarray(ti.f32, 1 << 18), 20)),
             ("two threads, 1 MB each x 20", sweep_both, (ti.ndarray(ti.f32, 1 << 19), 20)))
    times: dict[str, list[float]] = {name: [] for name, _, _ in cases}
    for name, f, args in cases:
        f(*args)  # compile
    for _ in range(rounds):
        for name, f, args in cases:
            t0 = time.perf_counter()
            f(*args)
            times[name].append(time.perf_counter() - t0)
    for name, t in times.items():
        t = sorted(t)
        med = statistics.median(t)
        print(f"{name:36s} min {1e3 * t[0]:7.3f} ms  median {1e3 * med:7.3f}  p90 {1e3 * t[int(0.9 * len(t))]:7.3f}"
              f"  median/min {med / t[0]:.2f}")
    return 0
