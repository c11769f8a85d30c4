"""One core per Taichi CPU worker: pinning Taichi's thread pool (Linux).

Taichi 1.7's CPU backend runs every parallel loop on its own pool of worker threads
(``cpu_max_num_threads`` of them, one per core by default); the Python thread only waits.
Its workers sleep between loops, and the kernel's scheduler places a woken worker where it
sees fit. On the project's 2-core benchmark machine (a Firecracker VM; ``sched_vcpu_pack`` on
its kernel command line) both workers often ran on one vCPU after an env step: the splat
camera's loops of a few milliseconds then took as long as on one thread. Pinning worker i to
core i (what ``OMP_PROC_BIND`` does for OpenMP) keeps them apart. ``BENCHMARKS.md`` has
the measurements.

The pool's threads are not named, so :func:`pin_taichi_workers` finds them by what they
do: the threads that ``ti.init`` created and that run a short parallel probe loop. It pins
only a pool that has one worker per core the process may use (Ray or process collection
gives each process fewer threads than cores, ``GAUSSTAC_CPU_THREADS``: those are left to the
scheduler) and never when ``GAUSSTAC_CPU_PIN=0``.
"""

import os

import taichi as ti

from . import environment

__all__ = ["thread_ids", "pin_taichi_workers"]

#: probe loop: items per worker (about 20 ms of work each), and sine terms per item (about 10 µs)
_PROBE_ITEMS_PER_WORKER, _PROBE_WORK = 2048, 1000
#: probes before giving up (each twice as long as the last): a loaded machine (``make test``'s two
#: processes on two cores) once left a worker out of a single probe, and the pool unpinned
_PROBE_ATTEMPTS = 4


def thread_ids() -> set[int]:
    """Kernel thread ids of this process (empty where ``/proc`` is not there)."""
    try:
        return {int(t) for t in os.listdir("/proc/self/task")}
    except OSError:
        return set()


def _run_ns(tid: int) -> int:
    """Nanoseconds thread ``tid`` has run on a CPU (``/proc/self/task/<tid>/schedstat``;
    -1 when the thread is gone or the file is missing)."""
    try:
        with open(f"/proc/self/task/{tid}/schedstat") as f:
            return int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return -1


@ti.kernel
def _probe(out: ti.types.ndarray(dtype=ti.f32, ndim=1), work: ti.i32):
    """A parallel loop long enough (about 20 ms) for every pool worker to take part."""
    for i in range(out.shape[0]):
        s = ti.f32(i)
        for k in range(work):
            s += ti.sin(s * 1e-3 + k)
        out[i] = s


def pin_taichi_workers(before: set[int], n_threads: int) -> list[int]:
    """Pin Taichi's CPU pool workers one per core, if the pool has one worker per core.

    Args:
        before: the thread ids that existed before ``ti.init`` (:func:`thread_ids`).
        n_threads: the pool's size (``cpu_max_num_threads``).

    Returns:
        The pinned workers' thread ids, worker k on the k-th core of the process's
        affinity set (empty: nothing pinned — disabled, not Linux, a pool smaller than
        the cores, or its workers not all found).
    """
    if environment.read("GAUSSTAC_CPU_PIN") == "0" or not hasattr(os, "sched_setaffinity"):
        return []
    cores = sorted(os.sched_getaffinity(0))
    if n_threads != len(cores) or n_threads < 2:
        return []
    out = ti.ndarray(ti.f32, _PROBE_ITEMS_PER_WORKER * n_threads)
    _probe(out, 0)  # compiled first: a compiler thread must not count as a worker
    ti.sync()
    new = sorted(thread_ids() - before)
    for attempt in range(_PROBE_ATTEMPTS):
        # on a loaded machine a worker may not get a core during one probe (another process
        # holds it): probe again, longer, until every worker has run in one probe
        start = {t: _run_ns(t) for t in new}
        _probe(out, _PROBE_WORK << attempt)
        ti.sync()
        workers = [t for t in new if start[t] >= 0 and _run_ns(t) > start[t]]
        if len(workers) == n_threads:
            break
    else:
        return []
    try:
        for core, tid in zip(cores, workers):
            os.sched_setaffinity(tid, {core})
    except OSError:
        return []
    return workers
