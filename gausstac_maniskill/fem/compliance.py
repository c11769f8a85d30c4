"""A body's compliance at all its surface points, computed once and kept on disk.

The compliance W of a :class:`~.contact.QuasiStaticBody` among its S surface points is the
symmetric [3S, 3S] matrix whose entry ((d, j), (s, i)) is the displacement [m] of point s along
axis i under a unit force [N] at point d along axis j. With all of it at hand, a press or a
slide costs dense algebra on the contact patch only, instead of three sparse solves for every
point it reaches the first time.

It costs 3S solves with the body's factor: at the index pad's 0.5 mm elements (S = 1994
points, 41 715 unknowns) about 75 s on one core. :func:`surface_compliance` splits them over
worker processes (each factors the stiffness itself), shows a progress bar, symmetrises the
result and stores E·W in float32 (36 S² bytes: 143 MB for that pad) under :func:`cache_dir`,
keyed by the body's elements, bond, points and ν: later runs, and other pads of the same
shape, load it in a fraction of a second. The cache holds derived data only: a file that
cannot be read is computed again (with a warning naming it), never trusted.
"""
from __future__ import annotations

import hashlib
import os
import warnings
from pathlib import Path

import numpy as np

__all__ = ["cache_dir", "compliance_key", "surface_compliance", "estimated_bytes"]

#: Bump when the stored layout or the way W is computed changes: old files are then ignored.
FORMAT = 1
#: Work (surface points × unknowns) under which the columns are solved in this process: below
#: it, starting worker processes (about 2 s each, factor included) costs more than it saves.
PARALLEL_WORK = 2e7
#: Points per task handed to a worker (one multi-right-hand-side solve of 3 × this many columns).
CHUNK = 32


def cache_dir() -> Path | None:
    """Where computed compliances are kept: ``$GAUSSTAC_CACHE_DIR`` if set (``off``: nowhere,
    compute each time), else ``$XDG_CACHE_HOME/gausstac_maniskill`` (``~/.cache/gausstac_maniskill``)."""
    env = os.environ.get("GAUSSTAC_CACHE_DIR")
    if env is not None:
        return None if env.strip().lower() in ("off", "0", "") else Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "gausstac_maniskill"


def compliance_key(body) -> str:
    """Hex digest naming ``body``'s compliance up to its Young's modulus (W ∝ 1/E): its
    elements, element size, fixed degrees of freedom, surface points (to 1e-6 of an element)
    and their elements, and ν."""
    b = body.body
    h = hashlib.sha256()
    points = np.round((body.points - b.origin) / b.size * 1e6).astype(np.int64)
    for a in (b.voxels, body.fixed, points, body.point_elements):
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    h.update(repr((FORMAT, round(b.size, 15), round(body.nu, 15))).encode())
    return h.hexdigest()[:32]


def surface_compliance(body, workers: int | None = None, progress: bool = True, cache: bool = True) -> np.ndarray:
    """W [3S, 3S] float32 [m/N] of ``body`` (a :class:`~.contact.QuasiStaticBody`), symmetric,
    rows and columns ordered (point, axis) as above: loaded from :func:`cache_dir` when there,
    else computed (and stored there, with ``cache``).

    Args:
        workers: processes solving the columns (default: the CPUs this process may use, at
            most one per 32 points; 1 for a body under :data:`PARALLEL_WORK`).
        progress: a progress bar while computing.
        cache: read and write the disk cache (when :func:`cache_dir` is not off).
    """
    S = body.num_points
    folder = cache_dir() if cache else None
    path = None if folder is None else folder / f"compliance-{compliance_key(body)}.npy"
    if path is not None and path.exists():
        try:
            scaled = np.load(path, allow_pickle=False)
            if scaled.shape != (3 * S, 3 * S) or scaled.dtype != np.float32 or not np.isfinite(scaled).all():
                raise ValueError(f"holds {scaled.dtype} {scaled.shape}, expected float32 {(3 * S, 3 * S)} finite")
            scaled /= np.float32(body.E)
            return scaled
        except (OSError, ValueError) as err:
            warnings.warn(f"{body.name}: the cached compliance {path} cannot be used ({err}); computing it again",
                          stacklevel=2)
    scaled = _compute(body, workers, progress)
    if path is not None:
        _store(scaled, path, body.name)
    scaled /= np.float32(body.E)
    return scaled


def _store(scaled: np.ndarray, path: Path, name: str) -> None:
    """Write ``scaled`` to ``path`` atomically (a partial file is never seen); a failure to
    write only warns (the result is in memory)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as fh:
            np.save(fh, scaled, allow_pickle=False)
        os.replace(tmp, path)
    except OSError as err:
        warnings.warn(f"{name}: could not keep the compliance in {path} ({err}); it will be computed again next time",
                      stacklevel=3)
        tmp.unlink(missing_ok=True)


def _cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _compute(body, workers: int | None, progress: bool) -> np.ndarray:
    """E·W [3S, 3S] float32, symmetrised, from 3S solves (in ``workers`` processes)."""
    from tqdm.auto import tqdm

    S = body.num_points
    chunks = [np.arange(a, min(a + CHUNK, S)) for a in range(0, S, CHUNK)]
    if workers is None:
        workers = 1 if S * body.num_free < PARALLEL_WORK else _cpus()
    workers = max(1, min(int(workers), len(chunks)))
    bar = tqdm(total=S, desc=f"{body.name}: compliance at {S} surface points (once; cached)", unit="point",
               disable=not progress, leave=False)
    with bar:
        out = None
        if workers > 1:
            try:
                out = _compute_in_processes(body, workers, bar)
            except (OSError, RuntimeError) as err:  # a worker could not start or died: one process does it all
                warnings.warn(f"{body.name}: computing the compliance in {workers} worker processes failed ({err}); "
                              "computing it in this process instead", stacklevel=3)
                bar.reset()
        if out is None:
            out = np.empty((S, 3, S, 3), np.float32)
            for chunk in chunks:
                out[chunk] = _columns(body, chunk)
                bar.update(len(chunk))
    flat = out.reshape(3 * S, 3 * S)
    flat += flat.T  # W is symmetric (Maxwell-Betti); the solves agree with that to rounding
    flat *= np.float32(0.5)
    return flat


def _columns(body, points: np.ndarray) -> np.ndarray:
    """E·W rows of ``points`` [k] as [k, 3 (j), S, 3 (i)] float32."""
    return (body.solve_columns(points).transpose(0, 3, 1, 2) * body.E).astype(np.float32)


def _compute_in_processes(body, workers: int, bar) -> np.ndarray:
    """The rows of E·W [S, 3, S, 3] solved by ``workers`` fresh Python processes
    (``python -m gausstac_maniskill.fem.compliance``), each factoring the body itself and
    writing its share of the rows into one memory-mapped file. Fresh interpreters, not
    multiprocessing: a fork would copy Taichi's and BLAS's threads in an unknown state, and
    multiprocessing's spawn re-runs the user's script in each worker unless it is guarded by
    ``if __name__ == "__main__"``."""
    import pickle
    import selectors
    import subprocess
    import sys
    import tempfile

    S = body.num_points
    with tempfile.TemporaryDirectory(prefix="gausstac-compliance-") as tmp:
        desc, rows = os.path.join(tmp, "body.pkl"), os.path.join(tmp, "rows.npy")
        with open(desc, "wb") as fh:
            pickle.dump(body, fh)
        np.lib.format.open_memmap(rows, mode="w+", dtype=np.float32, shape=(S, 3, S, 3)).flush()
        # the workers import this package as this process found it (an uninstalled checkout on sys.path too)
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1",
                   PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
        # stderr to files, not pipes: a worker that writes much there would block on a full pipe
        # that this process reads only at the end
        logs = [open(os.path.join(tmp, f"worker{w}.err"), "w+") for w in range(workers)]
        procs = [subprocess.Popen([sys.executable, "-m", __name__, desc, rows, str(w), str(workers), str(CHUNK)], env=env,
                                  stdout=subprocess.PIPE, stderr=log, text=True)
                 for w, log in enumerate(logs)]
        sel = selectors.DefaultSelector()
        for p in procs:
            sel.register(p.stdout, selectors.EVENT_READ)
        open_pipes = len(procs)
        while open_pipes:  # each worker prints the number of points of each chunk it finishes
            for key, _ in sel.select():
                line = key.fileobj.readline()
                if not line:
                    sel.unregister(key.fileobj)
                    open_pipes -= 1
                elif line.strip().isdigit():
                    bar.update(int(line))
        codes = [p.wait() for p in procs]
        for p in procs:
            p.stdout.close()
        errors = []
        for log in logs:
            log.seek(0)
            errors.append(log.read())
            log.close()
        failed = [(rc, err) for rc, err in zip(codes, errors) if rc != 0]
        if failed:
            rc, err = failed[0]
            raise RuntimeError(f"a worker exited with status {rc}: "
                               f"{err.strip().splitlines()[-1] if err.strip() else 'no message'}")
        return np.array(np.load(rows, mmap_mode="r"))


def _worker(desc: str, rows: str, index: int, count: int, chunk: int) -> None:
    """One worker of :func:`_compute_in_processes`: the chunks (of ``chunk`` points) ``index``,
    ``index + count``, …"""
    import pickle

    with open(desc, "rb") as fh:
        body = pickle.load(fh)  # assembles and factors the body
    out = np.load(rows, mmap_mode="r+")
    S = body.num_points
    for a in range(index * chunk, S, count * chunk):
        points = np.arange(a, min(a + chunk, S))
        out[points] = _columns(body, points)
        print(len(points), flush=True)
    out.flush()


def estimated_bytes(num_points: int) -> int:
    """Memory [bytes] of the float32 compliance of ``num_points`` surface points."""
    return 36 * int(num_points) ** 2


if __name__ == "__main__":
    import sys

    _worker(sys.argv[1], sys.argv[2], *map(int, sys.argv[3:6]))
