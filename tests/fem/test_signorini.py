"""The contact problems on points: the complementarity solver against every active set, and
the frictional solvers (semismooth Newton, Tresca iterations) against the Coulomb conditions."""
import itertools

import numpy as np
import pytest

from gausstac_maniskill.fem import solve_lcp


def test_lcp_matches_enumeration():
    """Against every active set of a small problem: the one satisfying all conditions is the answer."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        G = rng.normal(size=(6, 6))
        A = G @ G.T + 0.1 * np.eye(6)
        b = rng.normal(size=6)
        lam = solve_lcp(A, b)
        found = None
        for k in range(7):
            for S in itertools.combinations(range(6), k):
                x = np.zeros(6)
                if S:
                    x[list(S)] = np.linalg.solve(A[np.ix_(S, S)], -b[list(S)])
                w = A @ x + b
                if (x >= -1e-12).all() and (w >= -1e-10).all():
                    found = x
        assert found is not None
        assert np.allclose(lam, found, atol=1e-9)


def _coulomb_violations(W, n, gap0, slip0, mu, f, state):
    """Largest violations of the contact conditions: gap, pull, cone [N], stuck slip [m], and the
    largest cosine between a slipping point's slip and its friction force (should be −1)."""
    from gausstac_maniskill.fem.signorini import tangent_bases

    frame = np.concatenate([n[:, None, :], tangent_bases(n)], axis=1)
    fl = np.einsum("pai,pi->pa", frame, f)
    disp = np.einsum("pai,piqj,qj->pa", frame, W, f)
    gap, slip = gap0 + disp[:, 0], slip0 + disp[:, 1:]
    ft = np.linalg.norm(fl[:, 1:], axis=1)
    sliding = state == 2
    cos = np.einsum("pa,pa->p", slip[sliding], fl[sliding, 1:]) / np.maximum(
        np.linalg.norm(slip[sliding], axis=1) * ft[sliding], 1e-300)
    return dict(penetration=max(0.0, -gap.min()), open_gap=np.abs(gap[fl[:, 0] > 0]).max(initial=0.0),
                pull=max(0.0, -fl[:, 0].min()), cone=max(0.0, (ft - mu * fl[:, 0]).max()),
                stuck_slip=np.linalg.norm(slip[state == 1], axis=1).max(initial=0.0), cos=cos.max(initial=-1.0))


@pytest.mark.parametrize("method", ["newton", "tresca"])
def test_frictional_solver_meets_every_coulomb_condition(method, monkeypatch):
    """Both solvers: semismooth Newton (the default) and the Tresca iterations it falls back on."""
    from gausstac_maniskill.fem import signorini, solve_frictional
    from gausstac_maniskill.fem.signorini import BOUND_TOL

    if method == "tresca":
        monkeypatch.setattr(signorini, "NEWTON_ITERATIONS", 0)

    rng = np.random.default_rng(1)
    m = 12
    G = rng.normal(size=(3 * m, 3 * m))
    W = (G @ G.T / (3 * m) + 0.5 * np.eye(3 * m)).reshape(m, 3, m, 3) * 1e-4
    n = rng.normal(size=(m, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    gap0 = rng.normal(size=m) * 1e-5 - 5e-6
    slip0 = rng.normal(size=(m, 2)) * 5e-6
    for mu in (0.2, 1.0):
        f, state = solve_frictional(W, n, gap0, slip0, mu, tol=1e-10)
        v = _coulomb_violations(W, n, gap0, slip0, mu, f, state)
        assert v["penetration"] < 1e-9 and v["open_gap"] < 1e-9 and v["pull"] == 0.0
        # the cone holds exactly for Newton (its forces are projected on it), to the bound's
        # settling tolerance (BOUND_TOL of the largest bound) for the Tresca iterations
        cone = 1e-12 if method == "newton" else BOUND_TOL
        assert v["cone"] <= cone * mu * np.abs(f).max() and v["stuck_slip"] < 1e-8
        assert v["cos"] < -0.999  # a slipping point is pulled back along its slip
        assert (state == 2).any() and (state == 1).any()
        # a warm start with no point loaded (the last step's points all came open) finds the same contact
        f_warm, state_warm = solve_frictional(W, n, gap0, slip0, mu, tol=1e-10, f0=np.zeros((m, 3)))
        np.testing.assert_allclose(f_warm, f, atol=1e-6 * np.abs(f).max())
        assert (state_warm == state).all()
    for f0 in (np.zeros((m, 3)), f):  # nothing touches, from rest or from the last contact (its forces
        # all come open at once, as under random actions in GaussTac-Touch-v1)
        f_open, state = solve_frictional(W, n, np.abs(gap0) + 1e-6, slip0, 0.5, tol=1e-10, f0=f0)
        assert not f_open.any() and not state.any()
