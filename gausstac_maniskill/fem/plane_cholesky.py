"""Pᵀ K⁻¹ Q for a lattice body's stiffness K, by a Cholesky factor taken plane by plane.

A Q1 cube element couples only nodes one lattice step apart. Numbered plane by plane along one
lattice axis, a lattice body's unknowns give a block-tridiagonal K (block i: the unknowns in
plane i), whose Cholesky factor K = L Lᵀ is block-bidiagonal:

    L_ii Lᵢᵢᵀ = K_ii − L_i,i−1 L_i,i−1ᵀ,     L_i,i−1 = K_i,i−1 L_i−1,i−1⁻ᵀ

with dense blocks (they fill in). On a thin pad the planes across its length are small (the
index pad at 0.5 mm elements: 45 planes of about 1 040 unknowns), so the blocks are dense
matrices that BLAS 3 works on at full speed, on every core.

Pᵀ K⁻¹ Q = (L⁻¹P)ᵀ (L⁻¹Q) needs only forward substitution, Y_i = L_ii⁻¹ (P_i − L_i,i−1 Y_i−1),
and each plane adds its Y_iᵀ Y_i to the product. The factor is used as it is computed: nothing
beyond two planes is kept. A load column is zero before its first plane, and so is its forward
solution: the columns are taken in the order of their first plane, and plane i works only on
those begun by then (on average half of them).

The planes before the middle one are swept from the first, those after it from the last, and
the middle plane comes last (a twisted factorization): a column meets only the planes between
its own and the middle, and each half's product is a quarter of the whole.
:func:`inverse_products` takes several products in one sweep, which factors K and
forward-substitutes each load set once (a pad's compliance and its maps' response together).
"""
from __future__ import annotations

import numpy as np

__all__ = ["lattice_planes", "inverse_between", "inverse_products"]


def lattice_planes(coordinates: np.ndarray) -> tuple[np.ndarray, int]:
    """The plane of each unknown along the lattice axis that gives the smallest planes.

    Args:
        coordinates: [n, 3] int, the lattice coordinates of each unknown's node.

    Returns:
        (plane [n] int, numbered 0… without gaps, along the chosen axis; that axis).

    The cost of :func:`inverse_between` grows as Σ bᵢ² over the planes' sizes bᵢ (the blocks'
    products with the load columns); the axis with the smallest sum is chosen.
    """
    coordinates = np.asarray(coordinates, np.int64)
    best = None
    for axis in range(3):
        _, plane = np.unique(coordinates[:, axis], return_inverse=True)
        cost = float((np.bincount(plane).astype(float) ** 2).sum())
        if best is None or cost < best[0]:
            best = (cost, plane.ravel(), axis)
    return best[1], best[2]


def _first_plane(M, plane: np.ndarray, count: int) -> np.ndarray:
    """[columns] the first plane (of ``count``) each column of sparse ``M`` is nonzero in;
    ``count`` where none (rows of ``plane`` ≥ ``count`` do not count)."""
    first = np.full(M.shape[1], count, np.int64)
    nonempty = np.diff(M.indptr) > 0
    if nonempty.any():
        first[nonempty] = np.minimum.reduceat(plane[M.indices], M.indptr[:-1][nonempty])
    return np.minimum(first, count)


class _Loads:
    """A load set [n, k] (sparse CSC) as one sweep meets it: its columns in the order of their
    first plane of the sweep, the columns begun by each plane, and the last plane's forward solution."""

    def __init__(self, M, plane: np.ndarray, count: int):
        first = _first_plane(M, plane, count)
        self.order = np.argsort(first, kind="stable")  # the sweep's column j is M's column order[j]
        self.begun = np.searchsorted(first[self.order], np.arange(count), side="right")  # columns begun by plane i
        self.rows = M[:, self.order].tocsr()
        self.Y = np.zeros((0, 0))  # the last plane's forward solution, on the columns begun by then

    def advance(self, i: int, rows: np.ndarray, L_inv: np.ndarray, G: np.ndarray | None) -> np.ndarray:
        """Y_i = L_ii⁻¹ M_i − G Y_i−1 on the columns begun by plane i (``rows``), where ``L_inv`` is
        L_ii⁻¹ and ``G`` is L_ii⁻¹ L_i,i−1 (None for the first plane): one dense product, and one
        with the sparse loads (a triangular solve is slower than a product)."""
        c = int(self.begun[i])
        Y = (self.rows[rows][:, :c].T @ L_inv.T).T  # (Fortran order: BLAS takes it as it is)
        last = self.Y.shape[1]
        if G is not None and last:
            Y[:, :last] -= G @ self.Y
        self.Y = Y
        return self.Y

    @property
    def columns(self) -> np.ndarray:
        """M's columns that the last forward solution holds, in its order."""
        return self.order[:self.Y.shape[1]]


def _chol(A: np.ndarray, name: str, where: str) -> np.ndarray:
    """The lower Cholesky factor L of a plane's Schur complement ``A`` (symmetric, C order), as
    the transpose (a view) of LAPACK's upper factor of Aᵀ = A taken in place in Fortran order (no
    copy); ``A`` is overwritten. A ValueError names ``name`` and ``where`` when it is not
    positive definite.

    On one BLAS thread: OpenBLAS's threaded factorization of these ~1 100-unknown planes, right
    after the sweep's threaded products, is slower than one thread (and scipy.linalg.cholesky
    also copies)."""
    import scipy.linalg as la

    from ..backend import blas_threads

    with blas_threads(1):
        U, info = la.lapack.dpotrf(A.T, lower=0, clean=1, overwrite_a=1)
    if info != 0:
        raise ValueError(f"{name}: the stiffness is not positive definite ({where}: a part of the body "
                         "held by nothing?)")
    return U.T


def _chol_inverse(A: np.ndarray, name: str, where: str) -> np.ndarray:
    """L⁻¹ for the lower Cholesky factor L of ``A`` (:func:`_chol`; ``A`` is overwritten), inverted
    in place in LAPACK's Fortran order (the transpose of U⁻¹), on one BLAS thread as :func:`_chol`."""
    import scipy.linalg as la

    from ..backend import blas_threads

    U = _chol(A, name, where).T
    with blas_threads(1):
        U_inv, info = la.lapack.dtrtri(U, lower=0, overwrite_c=1)
    if info != 0:  # (a singular factor: not reached after a successful factorization)
        raise ValueError(f"{name}: the stiffness is singular ({where})")
    return U_inv.T


#: Columns of the right factor per product in :func:`_add_product`.
PRODUCT_BLOCK = 4096
#: The same for a symmetric product, summed on and above its block diagonal only (and the blocks of
#: :func:`_mirror_upper`): narrower, so that the blocks left out are about half the product.
SYMMETRIC_BLOCK = 512


def _add_product(out: np.ndarray, Yp: np.ndarray, Yq: np.ndarray, upper: bool = False) -> None:
    """out += Ypᵀ Yq, by blocks of :data:`PRODUCT_BLOCK` columns of Yq. NumPy hands Yᵀ Y on one
    buffer to BLAS's dsyrk, which crashes (segmentation fault) beyond 16 384 columns (NumPy
    2.4.6, OpenBLAS 0.3.31: 1 200 × 16 500 crashes, × 14 000 does not); the blocks stay far below
    that, and keep the product's temporary small.

    ``upper`` (Yp is Yq, the product symmetric): only the blocks on and above the block diagonal
    (rows up to each column block's end), about half the work; :func:`_mirror_upper` fills the rest."""
    width = SYMMETRIC_BLOCK if upper else PRODUCT_BLOCK
    for j in range(0, Yq.shape[1], width):
        block = Yq[:, j:j + width]
        rows = min(j + width, Yp.shape[1]) if upper else Yp.shape[1]
        if rows and block.shape[1]:
            out[:rows, j:j + block.shape[1]] += Yp[:, :rows].T @ block


def _mirror_upper(out: np.ndarray) -> None:
    """Make the square ``out`` exactly symmetric from its blocks on and above the block diagonal
    (of :data:`SYMMETRIC_BLOCK`, as :func:`_add_product` with ``upper`` fills them): each diagonal
    block ← (B + Bᵀ)/2, each block below ← the transpose of its mirror above. In place."""
    m, w = out.shape[0], SYMMETRIC_BLOCK
    for i in range(0, m, w):
        d = out[i:i + w, i:i + w]
        d[...] = 0.5 * (d + d.T)
        out[i + w:, i:i + w] = out[i:i + w, i + w:].T


def _couple(K, L_inv: np.ndarray, prev: np.ndarray, r: np.ndarray, A: np.ndarray) -> np.ndarray:
    """L_r,prev = K_r,prev L_prev⁻ᵀ (its transpose is L_prev⁻¹ K_prev,r) for the plane of unknowns
    ``r`` after the eliminated plane ``prev`` (whose factor's inverse is ``L_inv``); takes its
    share L_r,prev L_r,prevᵀ off ``A`` (the plane's Schur complement, in place) and returns it."""
    C = (L_inv @ K[prev][:, r].toarray()).T
    A -= C @ C.T
    return C


def _sweep(K, rows: list, loads: list, pairs: list, plane: np.ndarray, name: str, bar):
    """Factor and forward-substitute along ``rows`` (the unknowns of each plane, in the sweep's
    order; ``plane`` [n] numbers them so, and ≥ len(rows) off the sweep), summing
    (L⁻¹Pᵢ)ᵀ(L⁻¹Pⱼ) over them for each pair (i, j) of ``pairs`` of the load sets ``loads``.

    Returns:
        (each pair's sum [cᵢ, cⱼ] on the columns of Pᵢ and Pⱼ begun along the sweep, in the
        sweep's column order; each load set's :class:`_Loads`, holding that order and the last
        plane's forward solution; the last L_ii⁻¹).
    """
    count = len(rows)
    sets = [_Loads(P, plane, count) for P in loads]
    outs = [np.zeros((int(sets[i].begun[-1]), int(sets[j].begun[-1])) if count else (0, 0)) for i, j in pairs]
    L_inv = C = None
    for i, r in enumerate(rows):
        A = K[r][:, r].toarray()
        if i:
            C = _couple(K, L_inv, rows[i - 1], r, A)
        L_inv = _chol_inverse(A, name, f"plane {i} of a sweep of {count}")
        G = None if C is None else L_inv @ C
        Y = [s.advance(i, r, L_inv, G) for s in sets]  # each load set's forward solution, once
        for out, (a, b) in zip(outs, pairs):
            _add_product(out[:Y[a].shape[1], :Y[b].shape[1]], Y[a], Y[b], upper=a == b)
        if bar is not None:
            bar.update(1)
    for out, (a, b) in zip(outs, pairs):
        if a == b:  # the symmetric sums were summed above the block diagonal only
            _mirror_upper(out)
    return outs, sets, L_inv


def inverse_between(K, plane: np.ndarray, P, Q=None, bar=None, name: str = "body", dtype=np.float64) -> np.ndarray:
    """Pᵀ K⁻¹ Q [p, q] of ``dtype`` (the module's twisted sweep; BLAS on
    :func:`~gausstac_maniskill.backend.cpu_threads` threads: this process's share of the CPU).

    Args:
        K: [n, n] sparse, symmetric positive definite, coupling only unknowns in the same or
            adjacent planes (a Q1 lattice body's stiffness on its free unknowns).
        plane: [n] int, each unknown's plane (:func:`lattice_planes`).
        P: [n, p] sparse load columns; Q: [n, q] sparse, or None for P (the result is then
            exactly symmetric: summed on and above the block diagonal, then mirrored).
        bar: a progress bar (tqdm) advanced by one per plane.
        name: what K belongs to, for error messages.
        dtype: the result's; float32 halves its memory (each half's sum is kept in float64 and
            rounded once into it, the middle plane's product block by block).

    Raises:
        ValueError: K couples planes that are not adjacent, or is not positive definite (a part
            of the body held by nothing).
    """
    if Q is None:
        return inverse_products(K, plane, [P], [(0, 0)], bar=bar, name=name, dtype=dtype)[0]
    return inverse_products(K, plane, [P, Q], [(0, 1)], bar=bar, name=name, dtype=dtype)[0]


def inverse_products(K, plane: np.ndarray, loads: list, pairs: list, bar=None, name: str = "body",
                     dtype=np.float64) -> list[np.ndarray]:
    """[Pᵢᵀ K⁻¹ Pⱼ for (i, j) in ``pairs``] of the load sets ``loads`` [n, pᵢ] (sparse), all from
    one sweep (:func:`inverse_between` for one product): K is factored once and each load set
    forward-substituted once, however many products use it. A pair (i, i) gives an exactly
    symmetric result, for about half the product work of a pair (i, j). ``K``, ``plane``,
    ``bar``, ``name``, ``dtype`` and the errors: as :func:`inverse_between`.

    A pad's compliance W = Nᵀ K⁻¹ N and its maps' response M = A K⁻¹ N share the point loads N:
    in one sweep N's forward substitution and the factor are paid once instead of twice.
    """
    import scipy.linalg as la
    import scipy.sparse as sp

    from ..backend import blas_threads, cpu_threads

    K = sp.csr_matrix(K, dtype=np.float64)
    plane = np.asarray(plane, np.int64)
    n = K.shape[0]
    if K.shape != (n, n) or plane.shape != (n,) or any(P.shape[0] != n for P in loads):
        raise ValueError(f"{name}: K {K.shape}, plane {plane.shape} and the loads do not match")
    if not pairs or any(not (0 <= i < len(loads) and 0 <= j < len(loads)) for i, j in pairs):
        raise ValueError(f"{name}: pairs {pairs} must name load sets 0…{len(loads) - 1}")
    coo = K.tocoo()
    if len(coo.row) and np.abs(plane[coo.row] - plane[coo.col]).max() > 1:
        raise ValueError(f"{name}: the stiffness couples unknowns more than one plane apart")
    loads = [sp.csc_matrix(P, dtype=np.float64) for P in loads]
    outs = [np.zeros((loads[i].shape[1], loads[j].shape[1]), dtype) for i, j in pairs]
    if n == 0:
        return outs
    count = int(plane.max()) + 1
    rows = np.split(np.argsort(plane, kind="stable"), np.cumsum(np.bincount(plane, minlength=count))[:-1])
    mid = count // 2
    with blas_threads(cpu_threads()):
        # the two halves, each swept toward the middle plane (its planes numbered from its far end);
        # each half's products go into the results at once (their buffers are then freed)
        halves = []
        for planes, numbering, side in ((rows[:mid], np.where(plane < mid, plane, count), mid - 1),
                                        (rows[:mid:-1], np.where(plane > mid, count - 1 - plane, count), mid + 1)):
            if not len(planes):  # a half with no plane
                continue
            parts, sets, L_inv = _sweep(K, planes, loads, pairs, numbering, name, bar)
            for out, part, (i, j) in zip(outs, parts, pairs):
                out[np.ix_(sets[i].columns, sets[j].columns)] += part
            del parts
            halves.append((sets, L_inv, rows[side]))
        # the middle plane, coupled to the last plane of each half
        r = rows[mid]
        A = K[r][:, r].toarray()
        Y = [P[r].toarray() for P in loads]
        for sets, L_inv, side in halves:
            C = _couple(K, L_inv, side, r, A)
            for y, s in zip(Y, sets):
                y[:, s.columns] -= C @ s.Y
        del halves
        L = _chol(A, name, "the middle plane")
        Y = [la.solve_triangular(L, y, lower=True, check_finite=False) for y in Y]
        for out, (i, j) in zip(outs, pairs):
            _add_product(out, Y[i], Y[j], upper=i == j)
        if bar is not None:
            bar.update(1)
    for out, (i, j) in zip(outs, pairs):
        if i == j:  # the halves' sums are symmetric, the middle plane's is above the block diagonal
            _mirror_upper(out)
    return outs
