"""A body's compliance at all its surface points, computed once and kept on disk.

The compliance W of a :class:`~.contact.QuasiStaticBody` among its S surface points is the
symmetric [3S, 3S] matrix whose entry ((d, j), (s, i)) is the displacement [m] of point s along
axis i under a unit force [N] at point d along axis j. With all of it at hand, a press or a
slide costs dense algebra on the contact patch only, instead of three sparse solves for every
point it reaches the first time.

W = Nᵀ K⁻¹ N for the point loads N [num_free, 3S]: 3S solves, all taken at once by the body's
stiffness factored lattice plane by lattice plane (:meth:`~.contact.QuasiStaticBody.inverse_between`,
dense BLAS 3 on every core). At the index pad's 0.5 mm elements (S = 1994 points, 46 743
unknowns) that is about 11 s on 2 cores, where SuperLU's column-by-column solves in two worker
processes took 114 s on the same host. :func:`surface_compliance` shows a progress bar and stores E·W in float32 (36 S²
bytes: 143 MB for that pad) in :func:`cache_dir`, keyed by the body's elements, bond, points
and ν: later runs, and other pads of the same shape, load it in a fraction of a second. The cache
holds derived data only: a file that cannot be read is computed again (with a warning naming
it), never trusted.

A readout's response M = A K⁻¹ N (a pad's tactile maps as M times the point forces,
:func:`readout_responses`) shares N with W. Named with the compliance (``readouts``), it comes
from W's own sweep: N's forward substitution and the factor are paid once, and the index pad's
W with its maps' M take 13–15 s instead of 28–30 s in two sweeps.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from ..cache import COMPLIANCES, array_digest, cached_array, folder, load_array, store_array
from ..errors import ConfigError

__all__ = ["cache_dir", "compliance_key", "surface_compliance", "readout_responses", "estimated_bytes"]

#: Bump when the stored layout or the way W is computed changes: old files are then ignored.
#: (The plane-by-plane factor and the column-by-column solves give the same W, to rounding.)
FORMAT = 1


def cache_dir() -> Path | None:
    """The folder computed compliances and readout responses are kept in (``compliances/`` of
    :mod:`gausstac_maniskill.cache`); None where the cache is off."""
    return folder(COMPLIANCES)


def compliance_key(body) -> str:
    """Hex digest naming ``body``'s compliance up to its Young's modulus (W ∝ 1/E): its
    elements (and their fill, for cut cells), element size, fixed degrees of freedom, surface
    points (to 1e-6 of an element) and their elements, and ν."""
    b = body.body
    points = np.round((body.points - b.origin) / b.size * 1e6).astype(np.int64)
    arrays = (b.voxels, body.fixed, points, body.point_elements) + (() if b.fill is None else (b.fill,))
    return array_digest(arrays, repr((FORMAT, round(b.size, 15), round(body.nu, 15))))[:32]


def surface_compliance(body, progress: bool = True, cache: bool = True, readouts: Sequence = ()) -> np.ndarray:
    """W [3S, 3S] float32 [m/N] of ``body`` (a :class:`~.contact.QuasiStaticBody`), symmetric,
    rows and columns ordered (point, axis) as above: loaded from :func:`cache_dir` when there,
    else computed (and stored there, with ``cache``).

    Args:
        progress: a progress bar while computing.
        cache: read and write the disk cache (when :func:`cache_dir` is not off).
        readouts: readouts ``A`` [R, 3V] (sparse) whose responses (:func:`readout_responses`)
            will be asked for, or a callable giving them (called only where W has to be
            computed). Where W has to be computed, those not yet at hand are computed
            in the same sweep (W and M share the point loads: their forward substitution and
            the stiffness's factor are paid once) and kept with the body until
            :func:`readout_responses` takes them (and on disk, with ``cache``).
    """
    S = body.num_points
    stem = f"compliance-{compliance_key(body)}"
    scaled = load_array(COMPLIANCES, body.name, stem, (3 * S, 3 * S), cache)
    if scaled is None:
        wanted = {}  # stem: the load set Aᵀ of each response computed alongside
        for A in (readouts() if callable(readouts) else readouts):
            A, rstem = _readout(body, A)
            if rstem in wanted or ("response", rstem) in body.derived:
                continue
            on_disk = load_array(COMPLIANCES, body.name, rstem, (A.shape[0], 3 * S), cache)
            if on_disk is not None:  # kept for readout_responses: the file is not read twice
                body.derived[("response", rstem)] = on_disk
            else:
                wanted[rstem] = body.dofs_to_free(A)
        loads = [body.point_loads(np.arange(S))] + list(wanted.values())
        also = f" and the response of {sum(P.shape[1] for P in loads[1:])} readouts" if wanted else ""
        # symmetric as computed (Maxwell-Betti); each response A K⁻¹ N as (Aᵀ)ᵀ K⁻¹ N
        results = _products(body, loads, [(0, 0)] + [(k, 0) for k in range(1, len(loads))],
                            [body.E] + [1.0] * len(wanted), progress,
                            f"{body.name}: compliance at {S} surface points{also}{_once(cache)}")
        scaled = results[0]
        for (rstem, _), M in zip(wanted.items(), results[1:]):
            body.derived[("response", rstem)] = M
            if cache:
                store_array(COMPLIANCES, M, rstem, body.name)
        if cache:
            store_array(COMPLIANCES, scaled, stem, body.name)
    scaled /= np.float32(body.E)
    return scaled


def _readout(body, A) -> tuple:
    """(``A`` as sorted CSR float64, the stem its response to ``body``'s point forces is kept under)."""
    import scipy.sparse as sp

    A = sp.csr_matrix(A, dtype=np.float64)
    A.sort_indices()
    # E too: M ∝ 1/E where A does not depend on E (compliance_key leaves E out)
    key = array_digest((A.indptr, A.indices, A.data), repr(float(body.E)))[:16]
    return A, f"readout-{compliance_key(body)}-{key}"


def readout_responses(body, A, progress: bool = True, cache: bool = True, what: str = "readouts") -> np.ndarray:
    """[R, 3S] float32: the response of R readouts r = A u, linear in ``body``'s nodal
    displacements u (``A`` [R, 3V] sparse, node-major degrees of freedom), to a unit force [N]
    at each surface point along each axis (columns ordered (point, axis), as W's): r = M f for
    point forces f [3S]. M = A K⁻¹ N, all of it at once as :func:`surface_compliance` computes
    W (or taken from that computation, where ``A`` was among its ``readouts``). Cached on
    disk as :func:`surface_compliance`, keyed by the body, its Young's modulus and the bytes of A;
    ``what`` names them on the progress bar."""
    A, stem = _readout(body, A)
    S, R = body.num_points, A.shape[0]
    computed = body.derived.pop(("response", stem), None)  # computed with the compliance
    if computed is not None:
        return computed

    def compute():
        return _products(body, [body.dofs_to_free(A), body.point_loads(np.arange(S))], [(0, 1)], [1.0], progress,
                         f"{body.name}: response of {R} {what}{_once(cache)}")[0]

    return cached_array(COMPLIANCES, body.name, stem, (R, 3 * S), compute, cache)


def _once(cache: bool) -> str:
    """The progress bar's note on whether the result will be kept on disk."""
    return " (once; cached)" if cache and cache_dir() is not None else ""


#: Memory [bytes] per entry of Pᵀ K⁻¹ Q that computing it takes at its peak: the float32 result
#: and one half's float64 sum (about a quarter of the entries for W), with room for the planes.
PEAK_BYTES_PER_ENTRY = 7


def available_memory(root: str = "/") -> int | None:
    """Memory [bytes] this process can still take now: Linux's MemAvailable, or less where the
    process's control group (a container's memory limit, v1 or v2, itself or an ancestor) leaves
    less (its limit less what the group uses, reclaimable file cache not counted); None where
    unknown. ``root``: where ``/proc`` and ``/sys`` are read (tests)."""
    out = None
    try:
        with open(os.path.join(root, "proc/meminfo")) as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    out = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    for headroom in _cgroup_headrooms(root):
        out = headroom if out is None else min(out, headroom)
    return out


#: A cgroup v1 "limit" at or above this is the kernel's "no limit" (2⁶³ rounded to a page).
_NO_LIMIT = 1 << 60


def _cgroup_headrooms(root: str):
    """Each memory limit over this process's control group and its ancestors: limit − (usage −
    inactive file cache) [bytes], from cgroup v2 (``memory.max``, ``memory.current``) or v1
    (``memory.limit_in_bytes``, ``memory.usage_in_bytes``). Nothing where none is set or readable."""
    try:
        with open(os.path.join(root, "proc/self/cgroup")) as fh:
            lines = fh.read().splitlines()
    except OSError:
        return
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        _, controllers, path = parts
        if controllers == "":  # v2: one hierarchy
            base, files = os.path.join(root, "sys/fs/cgroup"), ("memory.max", "memory.current", "inactive_file")
        elif "memory" in controllers.split(","):
            base, files = (os.path.join(root, "sys/fs/cgroup/memory"),
                           ("memory.limit_in_bytes", "memory.usage_in_bytes", "total_inactive_file"))
        else:
            continue
        # the group and each ancestor up to the mount's root (which, in a container, may be the group itself)
        rel = path.strip("/")
        while True:
            folder = os.path.join(base, rel)
            headroom = _headroom(folder, *files)
            if headroom is not None:
                yield headroom
            if not rel:
                break
            rel = os.path.dirname(rel)


def _headroom(folder: str, limit_file: str, usage_file: str, inactive_key: str) -> int | None:
    """limit − (usage − inactive file cache) [bytes] of one cgroup folder; None without a limit."""
    try:
        with open(os.path.join(folder, limit_file)) as fh:
            text = fh.read().strip()
        if text == "max" or int(text) >= _NO_LIMIT:
            return None
        limit = int(text)
        with open(os.path.join(folder, usage_file)) as fh:
            usage = int(fh.read().strip())
    except (OSError, ValueError):
        return None
    inactive = 0
    try:
        with open(os.path.join(folder, "memory.stat")) as fh:
            for line in fh:
                key, _, value = line.partition(" ")
                if key == inactive_key:
                    inactive = int(value)
                    break
    except (OSError, ValueError):
        pass
    return max(limit - max(usage - inactive, 0), 0)


def _products(body, loads: list, pairs: list, scales: list, progress: bool, desc: str) -> list[np.ndarray]:
    """[``scale`` × Pᵢᵀ K⁻¹ Pⱼ as float32 for each pair (i, j) of ``pairs`` and its scale] of the
    load sets ``loads`` (:meth:`~.contact.QuasiStaticBody.inverse_products`: one sweep), with a
    progress bar; ``desc`` names the work there and in the error.

    Raises:
        ConfigError: this machine has not the memory it takes (:data:`PEAK_BYTES_PER_ENTRY`).
    """
    from tqdm.auto import tqdm

    need = PEAK_BYTES_PER_ENTRY * sum(loads[i].shape[1] * loads[j].shape[1] for i, j in pairs)
    have = available_memory()
    if have is not None and need > have:
        raise ConfigError(
            f"{desc}: needs about {need / 2 ** 30:.1f} GiB of memory while it is computed, and this process has "
            f"{have / 2 ** 30:.1f} GiB available (the machine's free memory, or its container's limit). "
            "Leave the pad's compliance to be solved point by point "
            f"(fem_precompute=False, the default above fem.sensor.PRECOMPUTE_BYTES), or use a coarser grid.")
    with tqdm(total=body.num_planes, desc=desc, unit="plane", disable=not progress, leave=False) as bar:
        outs = body.inverse_products(loads, pairs, bar=bar, dtype=np.float32)
    for out, scale in zip(outs, scales):
        out *= np.float32(scale)
    return outs


def estimated_bytes(num_points: int) -> int:
    """Memory [bytes] of the float32 compliance of ``num_points`` surface points."""
    return 36 * int(num_points) ** 2

