"""Contact problems on the m points of an elastic body near a rigid collider: linear algebra alone.

A force f_d [N] at point d moves point s by W_sd f_d (W [m, 3, m, 3] [m/N], the body's compliance
among the points). With φ [m] the collider's signed distance at each point and n its outward
normal there, Signorini's conditions on the normal forces λ [N] (linearised at the present surface):

    λ ≥ 0,   g = φ + Σ_d (n_s · W_sd n_d) λ_d ≥ 0,   λ · g = 0,

a linear complementarity problem, solved exactly (:func:`solve_lcp`). Coulomb friction adds, for
the tangential force f_t [N] and the slip s = s0 + Tᵀ(W f) [m] (T: :func:`tangent_bases` of n, s0:
the offset from the point's hold on the collider):

    |f_t| ≤ μ λ,   s = 0 where |f_t| < μ λ,   f_t = −μ λ s / |s| where s ≠ 0,

solved by semismooth Newton on Alart and Curnier's equations, with Tresca iterations where it
does not converge (:func:`solve_frictional`).
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import SimulationError

__all__ = ["solve_lcp", "solve_frictional", "tangent_bases", "BOUND_TOL", "NEWTON_ITERATIONS"]


def solve_lcp(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """λ ≥ 0 with Aλ + b ≥ 0 and λ · (Aλ + b) = 0, for a symmetric positive definite ``A``
    [m, m]: the minimiser of ½ λᵀAλ + bᵀλ over λ ≥ 0, solved as the non-negative least
    squares problem min |Lᵀλ + L⁻¹b| (A = LLᵀ) by Lawson and Hanson's active-set method
    (finite, exact up to rounding)."""
    from scipy.linalg import cholesky, solve_triangular
    from scipy.optimize import nnls

    b = np.asarray(b, float)
    if not len(b):
        return np.zeros(0)
    A = 0.5 * (A + A.T)
    A[np.diag_indices(len(b))] += 1e-12 * np.trace(A) / len(b)
    L = cholesky(A, lower=True, check_finite=False)
    lam, _ = nnls(L.T, -solve_triangular(L, b, lower=True, check_finite=False), maxiter=50 * len(b))
    return lam


def tangent_bases(n: np.ndarray) -> np.ndarray:
    """[m, 2, 3] two unit tangents orthogonal to each unit normal ``n`` [m, 3] (and to each other)."""
    a = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(n, a)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return np.stack([t1, np.cross(n, t1)], axis=1)


#: The Coulomb bound μ f_n has settled when no point's moves by more than this fraction of the largest.
BOUND_TOL = 1e-4


def _xyz_rows(points: np.ndarray) -> np.ndarray:
    """[3m] the rows (point-major, 3 per point) of ``points`` [m] in a [3S] vector of point values."""
    return (3 * np.asarray(points)[:, None] + np.arange(3)).ravel()


def _block(M: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``M[np.ix_(rows, cols)]``, gathered rows first (whole rows are contiguous, so this is
    faster than ``np.ix_`` on the contact problems' matrices)."""
    return M.take(rows, axis=0).take(cols, axis=1)


def _project(f: np.ndarray, bound: np.ndarray) -> np.ndarray:
    """Each point's force [m, 3] (n, t1, t2) onto {f_n ≥ 0, |f_t| ≤ bound}."""
    out = f.copy()
    np.maximum(out[:, 0], 0.0, out=out[:, 0])
    ft = np.sqrt(f[:, 1] * f[:, 1] + f[:, 2] * f[:, 2])
    over = ft > bound
    if over.any():
        out[over, 1:] *= (bound[over] / ft[over])[:, None]
    return out


def solve_frictional(W: np.ndarray, n: np.ndarray, gap0: np.ndarray, slip0: np.ndarray, mu,
                     tol: float, max_iterations: int = 50, inner: int = 4000,
                     f0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Signorini contact with Coulomb friction on m points of an elastic body, quasi-static.

    Unknowns: the force f_p [3] on each point. Its displacement is W f (``W`` [m, 3, m, 3], the
    compliance among the points); its gap g = gap0 + n·(W f) and its slip s = slip0 + Tᵀ(W f)
    (T: :func:`tangent_bases` of ``n``; ``slip0`` [m, 2] its tangential offset from where it
    holds on the collider; ``mu``: μ, one value or [m]). Conditions: f_n = n·f ≥ 0, g ≥ 0,
    f_n g = 0; |f_t| ≤ μ f_n; a point that holds (|f_t| < μ f_n) does not slip; one that slips
    is pulled back along its slip.

    Solved by a semismooth Newton method on Alart and Curnier's equations (:func:`_newton`),
    to ``tol`` [m] in each point's displacement. Where Newton does not converge in
    :data:`NEWTON_ITERATIONS`, by a sequence of Tresca problems instead (the friction bound
    μ f_n of the last iterate held fixed, Panagiotopoulos's iteration; :func:`_solve_tresca`):
    each is the convex problem min ½fᵀWf + bᵀf over {f_n ≥ 0, |f_t| ≤ bound}, solved by
    accelerated projected gradients, until no bound moves by more than :data:`BOUND_TOL` of the
    largest (first-order: slow on a large, stiff patch; at most ``max_iterations`` problems of
    ``inner`` steps, else :class:`SimulationError`).

    The iteration starts from ``f0`` [m, 3] (forces in the frame of ``n``'s points, e.g. the
    last outer iteration's) or, without one, from the frictionless solution.

    Returns (f [m, 3], state [m] int: 0 open, 1 stuck, 2 slipping).
    """
    frame, M, b = _local_problem(W, n, gap0, slip0)
    m = len(gap0)
    mu = np.broadcast_to(np.asarray(mu, float), (m,))
    if f0 is None:
        f = np.zeros((m, 3))
        f[:, 0] = solve_lcp(M[0::3, 0::3], gap0)  # frictionless start
    else:
        f = np.einsum("pai,pi->pa", frame, np.asarray(f0, float).reshape(m, 3))
    solved = _newton(M, b, f, mu, tol, NEWTON_ITERATIONS) if m else None
    if solved is not None:
        f, state = solved
    else:
        f, bound = _solve_tresca(M, b, f, mu, tol, max_iterations, inner)
        ft = np.linalg.norm(f[:, 1:], axis=1)  # on the bound its last Tresca problem held: slipping
        state = np.where(f[:, 0] <= 0, 0, np.where(ft >= bound * (1 - 1e-6), 2, 1))
    return np.einsum("pai,pa->pi", frame, f), state


def _local_problem(W, n, gap0, slip0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The contact problem in each point's (n, t1, t2) frame: (frame [m, 3, 3] (rows n, t1,
    t2), M [3m, 3m] = frame_p W_pq frame_qᵀ (symmetrised), b [3m] = (gap0, slip0) per point)."""
    m = len(gap0)
    frame = np.concatenate([n[:, None, :], tangent_bases(n)], axis=1)
    half = np.matmul(frame, W.reshape(m, 3, 3 * m))  # [m, 3, 3m]: the rows turned, one point at a time
    M = np.matmul(half.reshape(3 * m, m, 3).transpose(1, 0, 2), frame.transpose(0, 2, 1))  # then the columns
    M = M.transpose(1, 0, 2).reshape(3 * m, 3 * m)
    M = 0.5 * (M + M.T)
    return frame, M, np.concatenate([gap0[:, None], slip0], axis=1).ravel()


#: Newton iterations before the frictional solve turns to Tresca iterations (a plate over the
#: whole index pad takes 10–12 from the last step's forces).
NEWTON_ITERATIONS = 40


def _coulomb_projection(M, b, f, mu, r):
    """Alart and Curnier's map at ``f`` [m, 3] (rows n, t1, t2): z = f − r (M f + b) (``r``
    [m], per point) and its projection P(z): P_n = max(0, z_n), P_t = z_t clipped to the disc
    of radius μ P_n. Returns (P, z, closed (z_n > 0), slipping (closed, |z_t| > μ z_n),
    |z_t|) [m]."""
    z = f - r[:, None] * (M @ f.ravel() + b).reshape(-1, 3)
    closed = z[:, 0] > 0
    bound = mu * np.maximum(z[:, 0], 0.0)
    zt = np.sqrt(z[:, 1] * z[:, 1] + z[:, 2] * z[:, 2])
    slipping = closed & (zt > bound)
    P = np.zeros_like(z)
    P[:, 0] = np.maximum(z[:, 0], 0.0)
    P[closed, 1:] = z[closed, 1:]
    P[slipping, 1:] *= (bound[slipping] / zt[slipping])[:, None]
    return P, z, closed, slipping, zt


def _newton(M, b, f, mu, tol, iterations) -> tuple[np.ndarray, np.ndarray] | None:
    """Coulomb friction on the points of ``M`` [3m, 3m] (rows n, t1, t2 per point), ``b``
    [3m], from ``f`` [m, 3]: a semismooth Newton method on the equations

        F(f) = f − P(f − r (M f + b)) = 0

    (Alart & Curnier 1991, Comput. Methods Appl. Mech. Eng. 92:353; :func:`_coulomb_projection`;
    r_p = 1 / M_pp,nn, the point's own normal compliance), whose roots are exactly the contact
    conditions of :func:`solve_frictional` (F_n = 0 is λ_n g = 0 with both ≥ 0, F_t = 0 is
    stick or slip against the slip on the cone). P is piecewise smooth, so Newton takes one
    element of its generalized Jacobian per point: 0 for an open point (its force is set to 0),
    the identity for a stuck one, and for a slipping one the derivative of z_t ↦ μ z_n z_t/|z_t|.
    The linear system is then on the closed points only, [3k, 3k], factored in float32 (an
    inexact Newton step; the residual is float64). Each step is cut by halves until
    Σ |F_p / r_p|² decreases.

    Converged when every point's |F_p| / r_p < ``tol`` [m] at an iterate and at its projection
    P (each point's gap and stuck slip are then within ``tol``). Returns (P: f_n ≥ 0 and |f_t| ≤
    μ f_n exactly [m, 3], state [m]: 0 open, 1 stuck, 2 slipping), or None where
    it does not converge in ``iterations`` or a step cannot decrease the residual (then
    :func:`_solve_tresca` takes over)."""
    r = 1.0 / np.diag(M)[0::3]

    def residual(f, P):  # each point's |F_p / r_p|² [m²]
        return np.sum(((f - P) / r[:, None]) ** 2, axis=1)

    P, z, closed, slipping, zt = _coulomb_projection(M, b, f, mu, r)
    res = residual(f, P)
    target = tol * tol
    for step in range(iterations + 1):
        if res.max() < target:  # converged: the answer is P, so P must pass too
            out = _coulomb_projection(M, b, P, mu, r)
            if residual(P, out[0]).max() < tol * tol:
                return P, np.where(out[2], np.where(out[3], 2, 1), 0)
            # P sits on a point's stick/slip kink, where a Newton step from P can lead back to
            # this iterate (a two-cycle): go on from the iterate instead, to a closer target
            target *= 0.01
        if step == iterations:
            return None
        delta = np.where(closed[:, None], 0.0, -f)  # an open point's force goes to 0
        if closed.any():  # the closed points' step: one linear system
            delta = _newton_step(M, f, P, z, closed, slipping, zt, mu, r, delta)
            if delta is None:
                return None
        alpha = 1.0
        for _ in range(12):  # cut the step until the residual decreases
            trial = f + alpha * delta
            out = _coulomb_projection(M, b, trial, mu, r)
            trial_res = residual(trial, out[0])
            if trial_res.sum() < res.sum():
                break
            alpha *= 0.5
        else:
            return None
        f, res = trial, trial_res
        P, z, closed, slipping, zt = out
    return None


def _newton_step(M, f, P, z, closed, slipping, zt, mu, r, delta):
    """The Newton step of :func:`_newton` on its closed points (``delta`` [m, 3] holds the open
    points' already): solves dF/df Δ = −F there. Returns ``delta``, or None where the step is
    singular."""
    import warnings

    from scipy.linalg import LinAlgWarning, lu_factor, lu_solve

    c = np.flatnonzero(closed)
    o = np.flatnonzero(~closed & np.any(f != 0.0, axis=1))  # open points that carry a force
    k = len(c)
    s = np.flatnonzero(slipping[c])  # slipping points, among the closed ones
    zh = z[c[s], 1:] / zt[c[s], None]
    D = np.zeros((len(s), 3, 3))  # dP/dz of a slipping point (a stuck one's is the identity)
    D[:, 0, 0] = 1.0
    mu_s = mu[c[s]]
    D[:, 1:, 1:] = (mu_s * z[c[s], 0] / zt[c[s]])[:, None, None] * (np.eye(2) - zh[:, :, None] * zh[:, None, :])
    D[:, 1:, 0] = mu_s[:, None] * zh
    rows = _xyz_rows(c)
    A = _block(M, rows, np.concatenate([rows, _xyz_rows(o)])) * np.repeat(r[c], 3)[:, None]  # r M
    Av = A.reshape(k, 3, -1)
    Av[s] = np.matmul(D, Av[s])  # D r M
    J = A[:, :3 * k]  # dF/df = I − D (I − r M) on the closed points
    Jv = J.reshape(k, 3, k, 3)
    Jv[s, :, s, :] += np.eye(3) - D
    rhs = (P - f)[c].ravel() + A[:, 3 * k:] @ f[o].ravel()  # −F_c − (dF_c/df_o) Δ_o, Δ_o = −f_o
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", LinAlgWarning)  # a singular step: the check below
        try:
            delta[c] = lu_solve(lu_factor(J.astype(np.float32), check_finite=False),
                                rhs.astype(np.float32), check_finite=False).reshape(k, 3)
        except (ValueError, np.linalg.LinAlgError):
            return None
    return delta if np.isfinite(delta).all() else None


def _solve_tresca(M, b, f, mu, tol, max_iterations, inner) -> tuple[np.ndarray, np.ndarray]:
    """Coulomb friction on the points of ``M`` [3m, 3m] (rows n, t1, t2 per point), ``b`` [3m],
    from ``f`` [m, 3]: Tresca problems with the bound μ f_n of the last iterate, until it settles
    (:func:`solve_frictional`), on the points with a normal force and those that would
    penetrate. The first problem is solved to ``tol``, later ones only as finely as the bound's
    remaining change warrants (at most 100× ``tol``), the last one to ``tol``. The matrix products run in
    float32 (their rounding, ~1e-7 of the displacements, is far below ``tol``). One Lipschitz
    constant serves every subset of points: M's largest eigenvalue bounds each principal
    submatrix's. Returns (f [m, 3], the last Tresca problem's bound [m])."""
    m = len(f)
    f = _project(f, np.full(m, np.inf))
    if not m:
        return f, np.zeros(0)
    L = float(np.linalg.eigvalsh(M)[-1]) if len(b) <= 1200 else _largest_eigenvalue(M)
    M32 = M.astype(np.float32)
    normal = M32[0::3]  # [m, 3m] the normal rows: every point's gap
    active = f[:, 0] > 0
    bound = mu * f[:, 0]
    loose = 1.0  # the first problem to tol: a loose start leaves the bound to settle on FISTA's noise
    for _ in range(max_iterations):
        idx = np.flatnonzero(active)
        rows = _xyz_rows(idx)
        if len(idx):  # (none: a warm start whose points all came open; the joins below decide)
            f[idx] = _fista(_block(M32, rows, rows), b[rows], f[idx], bound[idx], L, tol * loose, inner)
        f[~active] = 0.0
        join = ~active & (b[0::3] + normal[:, rows] @ f[idx].ravel().astype(np.float32) < -tol)
        new = mu * f[:, 0]
        change = np.abs(new - bound).max() / max(new.max(), 1e-300)
        if join.any():  # solve again with them, no more finely than now
            active |= join
        elif change <= BOUND_TOL and loose == 1.0:
            return f, bound
        else:
            loose = float(np.clip(change / (10.0 * BOUND_TOL), 1.0, 100.0))
        bound = new
    raise SimulationError(f"friction: the Coulomb bound did not settle in {max_iterations} Tresca iterations")


def _largest_eigenvalue(M: np.ndarray, iterations: int = 60) -> float:
    """λ_max of a symmetric positive semidefinite M by power iteration (+5 % margin)."""
    x = np.ones(len(M)) / np.sqrt(len(M))
    lam = 0.0
    for _ in range(iterations):
        y = M @ x
        lam = float(np.linalg.norm(y))
        x = y / max(lam, 1e-300)
    return 1.05 * lam


def _fista(M, b, f0, bound, L, tol, iterations) -> np.ndarray:
    """min ½fᵀMf + bᵀf over {f_n ≥ 0, |f_t| ≤ bound} from ``f0`` [m, 3]: FISTA with restart,
    stopped when a step moves the points' displacements by less than ``tol`` [m]."""
    x = _project(f0, bound)
    y, t = x.copy(), 1.0
    for _ in range(iterations):
        grad = (M @ y.ravel().astype(M.dtype) + b).reshape(-1, 3)
        x_new = _project(y - grad / L, bound)
        step = x_new - x
        if np.abs(step).max() * L < tol:
            return x_new
        t_new = 0.5 * (1.0 + math.sqrt(1.0 + 4.0 * t * t))
        if np.sum((y - x_new) * step) > 0:  # the momentum points uphill: restart
            y, t = x_new.copy(), 1.0
        else:
            y = x_new + (t - 1.0) / t_new * step
            t = t_new
        x = x_new
    raise SimulationError(f"friction: the Tresca problem did not converge in {iterations} iterations")
