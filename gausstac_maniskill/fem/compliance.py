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

__all__ = ["cache_dir", "array_digest", "cached_array", "compliance_key", "surface_compliance", "readout_responses",
           "estimated_bytes"]

#: Bump when the stored layout or the way W is computed changes: old files are then ignored.
FORMAT = 1
#: Work (solves × unknowns / 3, i.e. surface points × unknowns for the compliance) under which
#: the solves run in this process: below it, starting worker processes (about 2 s each, factor
#: included) costs more than it saves. Work above it goes to workers when this process has not
#: factored the body (the workers factor it instead: this process then never holds the factor),
#: and above three times it in any case.
PARALLEL_WORK = 1e7
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


def array_digest(arrays, extra: str = "") -> str:
    """Hex SHA-256 of ``arrays`` (each with its dtype and shape, C order) and then ``extra``:
    the key of what is computed from them (kept on disk or in this process)."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    h.update(extra.encode())
    return h.hexdigest()


def compliance_key(body) -> str:
    """Hex digest naming ``body``'s compliance up to its Young's modulus (W ∝ 1/E): its
    elements (and their fill, for cut cells), element size, fixed degrees of freedom, surface
    points (to 1e-6 of an element) and their elements, and ν."""
    b = body.body
    points = np.round((body.points - b.origin) / b.size * 1e6).astype(np.int64)
    arrays = (b.voxels, body.fixed, points, body.point_elements) + (() if b.fill is None else (b.fill,))
    return array_digest(arrays, repr((FORMAT, round(b.size, 15), round(body.nu, 15))))[:32]


def surface_compliance(body, workers: int | None = None, progress: bool = True, cache: bool = True) -> np.ndarray:
    """W [3S, 3S] float32 [m/N] of ``body`` (a :class:`~.contact.QuasiStaticBody`), symmetric,
    rows and columns ordered (point, axis) as above: loaded from :func:`cache_dir` when there,
    else computed (and stored there, with ``cache``).

    Args:
        workers: processes solving the columns (default: the CPUs this process may use, at
            most one per 32 points; 1 under :data:`PARALLEL_WORK`).
        progress: a progress bar while computing.
        cache: read and write the disk cache (when :func:`cache_dir` is not off).
    """
    S = body.num_points

    def compute():
        out = _responses(body, body.point_loads(np.arange(S)), body.E, workers, progress,
                         f"{body.name}: compliance at {S} surface points{_once(cache)}")
        flat = out.reshape(3 * S, 3 * S)  # rows (d, j), columns (s, i)
        flat += flat.T  # W is symmetric (Maxwell-Betti); the solves agree with that to rounding
        flat *= np.float32(0.5)
        return flat

    scaled = cached_array(body.name, f"compliance-{compliance_key(body)}", (3 * S, 3 * S), compute, cache)
    scaled /= np.float32(body.E)
    return scaled


def readout_responses(body, A, workers: int | None = None, progress: bool = True, cache: bool = True,
                      what: str = "readouts") -> np.ndarray:
    """[R, 3S] float32: the response of R readouts r = A u, linear in ``body``'s nodal
    displacements u (``A`` [R, 3V] sparse, node-major degrees of freedom), to a unit force [N]
    at each surface point along each axis (columns ordered (point, axis), as W's): r = M f for
    point forces f [3S]. M = A K⁻¹ Nᵀ = (N K⁻¹ Aᵀ)ᵀ (K symmetric): R solves, not 3S. Cached on
    disk as :func:`surface_compliance`, keyed by the body, its Young's modulus and the bytes of A;
    ``what`` names them on the progress bar."""
    import scipy.sparse as sp

    A = sp.csr_matrix(A, dtype=np.float64)
    A.sort_indices()
    # E too: M ∝ 1/E where A does not depend on E (compliance_key leaves E out)
    key = array_digest((A.indptr, A.indices, A.data), repr(float(body.E)))[:16]
    S, R = body.num_points, A.shape[0]

    def compute():
        out = _responses(body, body.dofs_to_free(A), 1.0, workers, progress,
                         f"{body.name}: response of {R} {what}{_once(cache)}")
        return out.reshape(R, 3 * S)

    return cached_array(body.name, f"readout-{compliance_key(body)}-{key}", (R, 3 * S), compute, cache)


def _once(cache: bool) -> str:
    """The progress bar's note on whether the result will be kept on disk."""
    return " (once; cached)" if cache and cache_dir() is not None else ""


def cached_array(name: str, stem: str, shape: tuple, compute, cache: bool = True) -> np.ndarray:
    """The float32 array ``shape`` kept under :func:`cache_dir` as ``stem``.npy, or ``compute()``
    (then kept there). A file that cannot be used is computed again, with a warning naming it
    (and ``name``, what it belongs to)."""
    folder = cache_dir() if cache else None
    path = None if folder is None else folder / f"{stem}.npy"
    if path is not None and path.exists():
        try:
            out = np.load(path, allow_pickle=False)
            if out.shape != shape or out.dtype != np.float32 or not np.isfinite(out).all():
                raise ValueError(f"holds {out.dtype} {out.shape}, expected float32 {shape} finite")
            return out
        except (OSError, ValueError) as err:
            warnings.warn(f"{name}: the cached {path} cannot be used ({err}); computing it again",
                          stacklevel=3)
    out = compute()
    if path is not None:
        _store(out, path, name)
    return out


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
        warnings.warn(f"{name}: could not keep {path} ({err}); it will be computed again next time",
                      stacklevel=4)
        tmp.unlink(missing_ok=True)


def _cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _responses(body, loads, scale: float, workers: int | None, progress: bool, desc: str) -> np.ndarray:
    """[C, S, 3] float32: ``scale`` × the surface points' displacements under each of the C
    load vectors ``loads`` [num_free, C] (sparse), in ``workers`` processes, with a progress bar."""
    from tqdm.auto import tqdm

    C = loads.shape[1]
    chunks = [np.arange(a, min(a + 3 * CHUNK, C)) for a in range(0, C, 3 * CHUNK)]
    if workers is None:
        work = C * body.num_free / 3
        workers = _cpus() if work >= 3 * PARALLEL_WORK or (work >= PARALLEL_WORK and not body.factored) else 1
    workers = max(1, min(int(workers), len(chunks)))
    bar = tqdm(total=C, desc=desc, unit="solve", disable=not progress, leave=False)
    with bar:
        if workers > 1:
            try:
                return _in_processes(body, loads, scale, workers, bar)
            except (OSError, RuntimeError) as err:  # a worker could not start or died: one process does it all
                warnings.warn(f"{body.name}: solving in {workers} worker processes failed ({err}); "
                              "solving in this process instead", stacklevel=4)
                bar.reset()
        out = np.empty((C, body.num_points, 3), np.float32)
        for cols in chunks:
            out[cols] = _solve(body, loads, cols, scale)
            bar.update(len(cols))
    return out


def _solve(body, loads, cols: np.ndarray, scale: float) -> np.ndarray:
    """[len(cols), S, 3] float32: ``scale`` × the surface response to load columns ``cols``."""
    return (body.surface_response(loads[:, cols]) * scale).astype(np.float32)


def _in_processes(body, loads, scale: float, workers: int, bar) -> np.ndarray:
    """:func:`_responses` by ``workers`` fresh Python processes
    (``python -m gausstac_maniskill.fem.compliance``), each factoring the body itself and
    writing its share of the columns into one memory-mapped file. Fresh interpreters, not
    multiprocessing: a fork would copy Taichi's and BLAS's threads in an unknown state, and
    multiprocessing's spawn re-runs the user's script in each worker unless it is guarded by
    ``if __name__ == "__main__"``."""
    import pickle
    import selectors
    import subprocess
    import sys
    import tempfile

    C = loads.shape[1]
    with tempfile.TemporaryDirectory(prefix="gausstac-compliance-") as tmp:
        desc, out = os.path.join(tmp, "body.pkl"), os.path.join(tmp, "out.npy")
        with open(desc, "wb") as fh:
            pickle.dump((body, loads, scale), fh)
        np.lib.format.open_memmap(out, mode="w+", dtype=np.float32, shape=(C, body.num_points, 3)).flush()
        # the workers import this package as this process found it (an uninstalled checkout on sys.path too)
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1",
                   PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
        # stderr to files, not pipes: a worker that writes much there would block on a full pipe
        # that this process reads only at the end
        logs = [open(os.path.join(tmp, f"worker{w}.err"), "w+") for w in range(workers)]
        procs = [subprocess.Popen([sys.executable, "-m", __name__, desc, out, str(w), str(workers), str(3 * CHUNK)],
                                  env=env, stdout=subprocess.PIPE, stderr=log, text=True)
                 for w, log in enumerate(logs)]
        sel = selectors.DefaultSelector()
        for p in procs:
            sel.register(p.stdout, selectors.EVENT_READ)
        open_pipes = len(procs)
        while open_pipes:  # each worker prints the number of columns of each chunk it finishes
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
        return np.array(np.load(out, mmap_mode="r"))


def _worker(desc: str, out_path: str, index: int, count: int, chunk: int) -> None:
    """One worker of :func:`_in_processes`: the chunks (of ``chunk`` columns) ``index``,
    ``index + count``, …"""
    import pickle

    with open(desc, "rb") as fh:
        body, loads, scale = pickle.load(fh)  # assembles the body (it factors on its first solve)
    out = np.load(out_path, mmap_mode="r+")
    C = loads.shape[1]
    for a in range(index * chunk, C, count * chunk):
        cols = np.arange(a, min(a + chunk, C))
        out[cols] = _solve(body, loads, cols, scale)
        print(len(cols), flush=True)
    out.flush()


def estimated_bytes(num_points: int) -> int:
    """Memory [bytes] of the float32 compliance of ``num_points`` surface points."""
    return 36 * int(num_points) ** 2


if __name__ == "__main__":
    import sys

    _worker(sys.argv[1], sys.argv[2], *map(int, sys.argv[3:6]))
