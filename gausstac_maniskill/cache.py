"""GaussTac's disk cache: files computed from others, kept between runs.

One root folder, :func:`root`: ``$GAUSSTAC_CACHE`` where set (``off`` or ``0``: no cache
is written), else ``$XDG_CACHE_HOME/gausstac_maniskill``, else ``~/.cache/gausstac_maniskill``
(:mod:`~gausstac_maniskill.environment`). One subfolder per kind of entry:

* ``compliances/``: the FEM pads' compliances (``compliance-<key>.npy``) and their maps'
  responses (``readout-<key>.npy``), float32 (:mod:`~gausstac_maniskill.fem.compliance`);
* ``sdfs/``: mesh colliders' sampled signed distances (``sdf-<key>.npy``, float32 [m],
  :class:`~gausstac_maniskill.geometry.MeshCollider`);
* ``cores/<key>/``: the URDFs whose pad links collide through their rigid cores, with the
  cores' meshes (:func:`~gausstac_maniskill.agents.base.core_urdf`);
* ``floating/<key>/``: the floating Allegro hand's URDF (:mod:`~gausstac_maniskill.agents.allegro`).

Every key is a digest of what the entry is computed from (:func:`array_digest`), so an entry
is never stale; the cache holds derived data only and may be deleted. An array that cannot be
read is computed again, with a warning naming it (:func:`cached_array`). Files that must be
on disk to be used (the URDFs SAPIEN loads) go to the temporary folder where the cache is off
or cannot be written (:func:`cache_dir`).
"""
from __future__ import annotations

import hashlib
import os
import tempfile
import warnings
from pathlib import Path

import numpy as np

from . import environment

__all__ = ["COMPLIANCES", "SDFS", "CORES", "FLOATING", "root", "folder", "cache_path", "cache_dir",
           "array_digest", "cached_array", "load_array", "store_array"]

#: The subfolders, one per kind of entry (module docstring).
COMPLIANCES, SDFS, CORES, FLOATING = "compliances", "sdfs", "cores", "floating"


def root() -> Path | None:
    """The cache's root folder (module docstring); None where ``GAUSSTAC_CACHE`` is ``off``."""
    value = environment.read("GAUSSTAC_CACHE")
    if value.strip().lower() in ("off", "0"):
        return None
    if value:
        return Path(value).expanduser()
    base = environment.read("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "gausstac_maniskill"


def folder(*parts: str) -> Path | None:
    """``root() / parts...`` (not created); None where the cache is off."""
    top = root()
    return None if top is None else top.joinpath(*parts)


def cache_path(*parts: str) -> Path:
    """``root() / parts...``; under the temporary folder where the cache is off. For files
    that must be on disk to be used: nothing in it is needed twice."""
    top = root()
    return (Path(tempfile.gettempdir(), "gausstac_maniskill") if top is None else top).joinpath(*parts)


def cache_dir(*parts: str) -> Path:
    """The folder :func:`cache_path` ``(*parts)``, created; under the temporary folder
    instead when the cache cannot be written (a read-only home)."""
    out = cache_path(*parts)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError:
        out = Path(tempfile.gettempdir(), "gausstac_maniskill", *parts)
        out.mkdir(parents=True, exist_ok=True)
    return out


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


def cached_array(kind: str, name: str, stem: str, shape: tuple, compute, cache: bool = True) -> np.ndarray:
    """The float32 array ``shape`` kept in :func:`folder` ``(kind)`` as ``stem``.npy, or
    ``compute()`` (then kept there, with ``cache``). A file that cannot be used is computed
    again, with a warning naming it (and ``name``, what it belongs to)."""
    out = load_array(kind, name, stem, shape, cache)
    if out is None:
        out = compute()
        if cache:
            store_array(kind, out, stem, name)
    return out


def load_array(kind: str, name: str, stem: str, shape: tuple, cache: bool = True) -> np.ndarray | None:
    """The float32 array ``shape`` kept in :func:`folder` ``(kind)`` as ``stem``.npy; None where
    there is none (or ``cache`` is False, or the cache off), or where it cannot be used (with a
    warning naming it and ``name``)."""
    where = folder(kind) if cache else None
    path = None if where is None else where / f"{stem}.npy"
    if path is not None and path.exists():
        try:
            out = np.load(path, allow_pickle=False)
            if out.shape != shape or out.dtype != np.float32 or not np.isfinite(out).all():
                raise ValueError(f"holds {out.dtype} {out.shape}, expected float32 {shape} finite")
            return out
        except (OSError, ValueError) as err:
            warnings.warn(f"{name}: the cached {path} cannot be used ({err}); computing it again",
                          stacklevel=4)
    return None


def store_array(kind: str, out: np.ndarray, stem: str, name: str) -> None:
    """Keep ``out`` in :func:`folder` ``(kind)`` as ``stem``.npy (nothing where the cache is off)."""
    where = folder(kind)
    if where is not None:
        _store(out, where / f"{stem}.npy", name)


def _store(out: np.ndarray, path: Path, name: str) -> None:
    """Write ``out`` to ``path`` atomically (a partial file is never seen); a failure to
    write only warns (the result is in memory)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as fh:
            np.save(fh, out, allow_pickle=False)
        os.replace(tmp, path)
    except OSError as err:
        warnings.warn(f"{name}: could not keep {path} ({err}); it will be computed again next time",
                      stacklevel=5)
        tmp.unlink(missing_ok=True)
