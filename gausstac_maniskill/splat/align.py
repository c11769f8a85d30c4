"""Scans of a hand: reading them, aligning them rigidly to samples of the URDF hand
(centroids + principal axes, then trimmed ICP) and labelling points with links.

Units: metres; transforms are 4x4 rigid matrices.
"""
from __future__ import annotations

import itertools
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..errors import AssetError
from ..transforms import as_pose_matrix, rotation_about, transform_points
from .gaussians import GaussianSet, load_ply
from .surface import ColoredMesh

__all__ = ["ScanAlignment", "load_scan", "align_point_clouds", "assign_links"]


def load_scan(path: str | os.PathLike) -> tuple[np.ndarray, GaussianSet | None, np.ndarray | None]:
    """Read a scan: an INRIA Gaussian ``.ply``, a point ``.ply``, ``.xyz`` or ``.npy``.

    ``.xyz``: whitespace-separated rows ``x y z [r g b]`` (colours 0..1 or 0..255).
    ``.npy``: an [n, 3] or [n, 6] array, same meaning.

    Returns:
        (points [n, 3] float64 metres, the GaussianSet if the file holds Gaussians
        else None, rgb [n, 3] in [0, 1] if the file has colours else None).

    Raises:
        AssetError: the file is missing, unreadable, of an unknown format, has
            fewer than 10 points or non-finite ones (names the file).
    """
    path = Path(path)
    if not path.is_file():
        raise AssetError(f"scan file not found: {path}")
    ext = path.suffix.lower()
    rgb = None
    if ext == ".ply":
        from plyfile import PlyData

        try:
            ply = PlyData.read(str(path))
        except Exception as err:  # noqa: BLE001
            raise AssetError(f"{path.name}: unreadable .ply ({type(err).__name__}: {err})") \
                from None
        names = [e.name for e in ply.elements]
        if "vertex" not in names:
            raise AssetError(f"{path.name}: element 'vertex' missing")
        props = {p.name for p in ply["vertex"].properties}
        if {"f_dc_0", "opacity", "scale_0", "rot_0"} <= props:
            g = load_ply(path)
            return g.means.double().numpy(), g, None
        for f in ("x", "y", "z"):
            if f not in props:
                raise AssetError(f"{path.name}: vertex property '{f}' missing")
        v = ply["vertex"]
        arr = np.stack([np.asarray(v[f], dtype=np.float64) for f in ("x", "y", "z")], 1)
        if {"red", "green", "blue"} <= props:
            rgb = np.stack([np.asarray(v[f], dtype=np.float64) for f in ("red", "green", "blue")],
                           1)
            rgb = rgb / 255.0 if rgb.max() > 1.0 else rgb
    elif ext in (".xyz", ".txt", ".npy"):
        try:
            arr = np.load(path) if ext == ".npy" else np.loadtxt(path, ndmin=2)
        except Exception as err:  # noqa: BLE001
            raise AssetError(f"{path.name}: unreadable point file ({type(err).__name__}: "
                             f"{err})") from None
        arr = np.asarray(arr, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[1] not in (3, 6):
            raise AssetError(f"{path.name}: points have shape {list(arr.shape)}, expected "
                             "[n, 3] (x y z) or [n, 6] (x y z r g b)")
        if arr.shape[1] == 6:
            rgb = arr[:, 3:]
            rgb = rgb / 255.0 if rgb.max() > 1.0 else rgb
        arr = arr[:, :3]
    else:
        raise AssetError(f"{path.name}: unknown scan format {ext!r} (use .ply, .xyz or .npy)")
    if len(arr) < 10:
        raise AssetError(f"{path.name}: only {len(arr)} points, need at least 10")
    if not np.all(np.isfinite(arr)):
        raise AssetError(f"{path.name}: points contain NaN or inf")
    return arr, None, None if rgb is None else np.clip(rgb, 0, 1)


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """4x4 rigid T minimising Σ |T a - b|² (rows are corresponding points)."""
    ca, cb = a.mean(0), b.mean(0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, cb - R @ ca
    return T


def _icp(src: np.ndarray, tree, dst: np.ndarray, dst_n: np.ndarray, T: np.ndarray,
         iters_p2p: int, iters_p2l: int, trim: float) -> tuple[np.ndarray, float]:
    """Trimmed ICP: point-to-point (Kabsch) iterations, then point-to-plane (Gauss-Newton).

    Returns (T, RMS nearest distance over the kept ``trim`` fraction).
    """
    workers = -1 if len(src) > 5000 else 1  # threads only pay off for big queries

    def matches(T):
        p = transform_points(T, src)
        d, j = tree.query(p, workers=workers)
        keep = d <= np.quantile(d, trim)
        return p, d, j, keep

    for _ in range(iters_p2p):
        p, d, j, keep = matches(T)
        dT = _kabsch(p[keep], dst[j[keep]])
        T = dT @ T
        if np.abs(dT[:3, :3] - np.eye(3)).max() < 1e-6 and np.abs(dT[:3, 3]).max() < 1e-7:
            break
    for _ in range(iters_p2l):
        p, d, j, keep = matches(T)
        p, q, n = p[keep], dst[j[keep]], dst_n[j[keep]]
        # r = (p - q)·n ; linearised in (ω, t): r + (p × n)·ω + n·t
        A = np.concatenate([np.cross(p, n), n], axis=1)
        r = np.einsum("ij,ij->i", p - q, n)
        x = np.linalg.lstsq(A.T @ A + 1e-12 * np.eye(6), -A.T @ r, rcond=None)[0]
        w, t = x[:3], x[3:]
        dT = np.eye(4)
        ang = np.linalg.norm(w)
        if ang > 0:
            dT[:3, :3] = rotation_about(w, ang)
        dT[:3, 3] = t
        T = dT @ T
        if ang < 1e-7 and np.linalg.norm(t) < 1e-8:
            break
    _, d, _, keep = matches(T)
    return T, float(np.sqrt(np.mean(d[keep] ** 2)))


@dataclass
class ScanAlignment:
    """Result of :func:`align_point_clouds`.

    Attributes:
        transform: [4, 4] scan frame -> hand (URDF root) frame.
        rms: trimmed RMS nearest-neighbour distance after alignment, metres.
        candidates: (initialisation name, rms) of every start tried.
    """

    transform: np.ndarray
    rms: float
    candidates: list


def _pca_starts(src: np.ndarray, reference: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """Centroids matched, principal axes matched in every proper order/sign flip."""
    def axes(p):
        _, V = np.linalg.eigh(np.cov((p - p.mean(0)).T))
        return V[:, ::-1]  # largest first

    cs, cr = src.mean(0), reference.mean(0)
    Vs, Vr = axes(src), axes(reference)
    starts = []
    # matched axes first (a full scan), then the other axis orders (a partial scan
    # can reorder the principal axes); each with the sign flips giving det = +1
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1, -1), repeat=3):
            R = Vr[:, list(perm)] @ np.diag(signs) @ Vs.T
            if np.linalg.det(R) < 0:
                continue
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = R, cr - R @ cs
            starts.append((f"pca{perm}{signs}", T))
    return starts


def align_point_clouds(scan: np.ndarray, reference: np.ndarray, reference_normals: np.ndarray,
                       init="pca", trim: float = 0.9, max_points: int = 20000,
                       refine: int = 3, seed: int = 0) -> ScanAlignment:
    """Rigid transform taking ``scan`` onto ``reference`` (oriented samples of the hand).

    Args:
        scan: [n, 3] points in an arbitrary frame, metres.
        reference: [m, 3] dense samples of the target surface, metres.
        reference_normals: [m, 3] their unit normals.
        init: ``"pca"`` — centroids matched, principal axes matched in each of
            the 24 proper orders/sign flips (a partial scan can reorder them);
            ``"identity"`` — start where the scan is (and also from the
            centroid-matched identity); or a [4, 4] guess of scan -> hand.
            Every start runs coarse point-to-point ICP on a subset; the
            ``refine`` best continue with point-to-plane ICP and the lowest
            trimmed RMS wins.
        trim: fraction of closest correspondences used per iteration (robust
            to partial overlap and stray points).
        max_points: scan points used by ICP (random subset).
        refine: how many of the best coarse results are refined to convergence.
        seed: seed of the random subsets.
    """
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    src = scan if len(scan) <= max_points else scan[rng.choice(len(scan), max_points, False)]
    if isinstance(init, str) and init == "pca":
        starts = _pca_starts(src, reference)
    elif isinstance(init, str) and init == "identity":
        T = np.eye(4)
        T[:3, 3] = reference.mean(0) - src.mean(0)
        starts = [("identity", np.eye(4)), ("centroid", T)]
    else:
        starts = [("guess", as_pose_matrix(init, "scan frame guess"))]
    # coarse: every start on a small subset (far-off starts make k-d queries slow)
    sub = src[rng.choice(len(src), min(len(src), 1500), False)]
    ref_idx = rng.choice(len(reference), min(len(reference), 10000), False)
    coarse_tree = cKDTree(reference[ref_idx])
    results = []
    for name, T0 in starts:
        T, rms = _icp(sub, coarse_tree, reference[ref_idx], reference_normals[ref_idx], T0,
                      30, 0, trim)
        results.append((rms, name, T))
    results.sort(key=lambda r: r[0])
    # the best few go on (small subset, point-to-plane); the lowest residual wins
    tree = cKDTree(reference)
    best = None
    for _, name, T in results[:refine]:
        T, rms = _icp(sub, tree, reference, reference_normals, T, 10, 20, trim)
        if best is None or rms < best[0]:
            best = (rms, T)
    # fine: the winner with all (up to max_points) scan points, to convergence
    T, rms = _icp(src, tree, reference, reference_normals, best[1], 2, 40, trim)
    return ScanAlignment(T, rms, [(n, float(r)) for r, n, _ in results])


def assign_links(points: np.ndarray, ref_points: np.ndarray, ref_links: np.ndarray,
                 meshes: Mapping[str, Sequence[ColoredMesh]], links: Sequence[str],
                 poses: Mapping[str, np.ndarray], k: int = 8
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Link of the nearest posed link surface for each world point.

    The ``k`` nearest surface samples propose candidate links; where they
    disagree (near joints, where link meshes meet or overlap) the exact
    point-to-triangle distance to each candidate link's posed mesh decides.

    Args:
        points: [n, 3] world points, metres.
        ref_points: [m, 3] world samples of the posed hand surface.
        ref_links: [m] index into ``links`` of each sample.
        meshes: link name -> its meshes in the link frame.
        links: link names.
        poses: link name -> [4, 4] world pose.

    Returns:
        (link index [n] into ``links``, distance to the nearest sample [n], metres).
    """
    import trimesh
    from scipy.spatial import cKDTree

    d, j = cKDTree(ref_points).query(points, k=min(k, len(ref_points)), workers=-1)
    d, j = d.reshape(len(points), -1), j.reshape(len(points), -1)
    cand = ref_links[j]
    label = cand[:, 0].astype(np.int64)
    amb = np.nonzero((cand != cand[:, :1]).any(axis=1))[0]
    if len(amb):
        best = np.full(len(amb), np.inf)
        for i in np.unique(cand[amb]):
            rows = np.nonzero((cand[amb] == i).any(axis=1))[0]
            m = trimesh.util.concatenate([c.mesh for c in meshes[links[i]]])
            m.apply_transform(poses[links[i]])
            _, dist, _ = trimesh.proximity.closest_point(m, points[amb[rows]])
            better = dist < best[rows]
            best[rows[better]] = dist[better]
            label[amb[rows[better]]] = i
    return label, d[:, 0]
