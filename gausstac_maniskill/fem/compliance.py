"""A body's compliance at all its surface points, computed once and kept on disk.

The compliance W of a :class:`~.contact.QuasiStaticBody` among its S surface points is the
symmetric [3S, 3S] matrix whose entry ((d, j), (s, i)) is the displacement [m] of point s along
axis i under a unit force [N] at point d along axis j. With all of it at hand, a press or a
slide costs dense algebra on the contact patch only, instead of three sparse solves for every
point it reaches the first time.

W = Nᵀ K⁻¹ N for the point loads N [num_free, 3S]: 3S solves, all taken at once by the body's
stiffness factored lattice plane by lattice plane (:meth:`~.contact.QuasiStaticBody.inverse_between`,
dense BLAS 3 on every core). At the index pad's 0.5 mm elements (S = 1994 points, 46 743
unknowns) that is about 20 s on 2 cores, where SuperLU's column-by-column solves in two worker
processes took 114 s on the same host. :func:`surface_compliance` shows a progress bar and stores E·W in float32 (36 S²
bytes: 143 MB for that pad) under :func:`cache_dir`, keyed by the body's elements, bond, points
and ν: later runs, and other pads of the same shape, load it in a fraction of a second. The cache
holds derived data only: a file that cannot be read is computed again (with a warning naming
it), never trusted.
"""
from __future__ import annotations

import hashlib
import os
import warnings
from pathlib import Path

import numpy as np

from ..errors import ConfigError

__all__ = ["cache_dir", "array_digest", "cached_array", "compliance_key", "surface_compliance", "readout_responses",
           "estimated_bytes"]

#: Bump when the stored layout or the way W is computed changes: old files are then ignored.
#: (The plane-by-plane factor computes the same W as the column solves before it, to rounding.)
FORMAT = 1


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


def surface_compliance(body, progress: bool = True, cache: bool = True) -> np.ndarray:
    """W [3S, 3S] float32 [m/N] of ``body`` (a :class:`~.contact.QuasiStaticBody`), symmetric,
    rows and columns ordered (point, axis) as above: loaded from :func:`cache_dir` when there,
    else computed (and stored there, with ``cache``).

    Args:
        progress: a progress bar while computing.
        cache: read and write the disk cache (when :func:`cache_dir` is not off).
    """
    S = body.num_points

    def compute():  # symmetric as computed (Maxwell-Betti)
        return _between(body, body.point_loads(np.arange(S)), None, body.E, progress,
                        f"{body.name}: compliance at {S} surface points{_once(cache)}")

    scaled = cached_array(body.name, f"compliance-{compliance_key(body)}", (3 * S, 3 * S), compute, cache)
    scaled /= np.float32(body.E)
    return scaled


def readout_responses(body, A, progress: bool = True, cache: bool = True, what: str = "readouts") -> np.ndarray:
    """[R, 3S] float32: the response of R readouts r = A u, linear in ``body``'s nodal
    displacements u (``A`` [R, 3V] sparse, node-major degrees of freedom), to a unit force [N]
    at each surface point along each axis (columns ordered (point, axis), as W's): r = M f for
    point forces f [3S]. M = A K⁻¹ N, all of it at once as :func:`surface_compliance` computes
    W. Cached on
    disk as :func:`surface_compliance`, keyed by the body, its Young's modulus and the bytes of A;
    ``what`` names them on the progress bar."""
    import scipy.sparse as sp

    A = sp.csr_matrix(A, dtype=np.float64)
    A.sort_indices()
    # E too: M ∝ 1/E where A does not depend on E (compliance_key leaves E out)
    key = array_digest((A.indptr, A.indices, A.data), repr(float(body.E)))[:16]
    S, R = body.num_points, A.shape[0]

    def compute():
        return _between(body, body.dofs_to_free(A), body.point_loads(np.arange(S)), 1.0, progress,
                        f"{body.name}: response of {R} {what}{_once(cache)}")

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


#: Memory [bytes] per entry of Pᵀ K⁻¹ Q that computing it takes at its peak: the float32 result
#: and one half's float64 sum (about a quarter of the entries for W), with room for the planes.
PEAK_BYTES_PER_ENTRY = 7


def available_memory() -> int | None:
    """Memory [bytes] this machine has available now (Linux's MemAvailable), None where unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _between(body, P, Q, scale: float, progress: bool, desc: str) -> np.ndarray:
    """``scale`` × Pᵀ K⁻¹ Q as float32 (:meth:`~.contact.QuasiStaticBody.inverse_between`), with a
    progress bar; ``desc`` names it there and in the error.

    Raises:
        ConfigError: this machine has not the memory it takes (:data:`PEAK_BYTES_PER_ENTRY`).
    """
    from tqdm.auto import tqdm

    need = PEAK_BYTES_PER_ENTRY * P.shape[1] * (P.shape[1] if Q is None else Q.shape[1])
    have = available_memory()
    if have is not None and need > have:
        raise ConfigError(
            f"{desc}: needs about {need / 2 ** 30:.1f} GiB of memory while it is computed, and this machine has "
            f"{have / 2 ** 30:.1f} GiB available. Leave the pad's compliance to be solved point by point "
            f"(fem_precompute=False, the default above fem.sensor.PRECOMPUTE_BYTES), or use a coarser grid.")
    with tqdm(total=body.num_planes, desc=desc, unit="plane", disable=not progress, leave=False) as bar:
        out = body.inverse_between(P, Q, bar=bar, dtype=np.float32)
    out *= np.float32(scale)
    return out


def estimated_bytes(num_points: int) -> int:
    """Memory [bytes] of the float32 compliance of ``num_points`` surface points."""
    return 36 * int(num_points) ** 2

