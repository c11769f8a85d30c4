"""Frictionless contact at equilibrium: the complementarity solver, the thin-layer theory,
and the product pad."""
import itertools
import math

import numpy as np
import pytest

from gausstac_maniskill.bench.quasistatic import layer_point, sphere
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.fem import layer_body, solve_lcp


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


@pytest.mark.parametrize("nu", [0.48, 0.499])
@pytest.mark.parametrize("a_over_h", [0.5, 1.0, 2.0])
def test_thin_layer_within_5_percent_at_four_elements(nu, a_over_h):
    """The 4 mm bonded layer with 1 mm elements (four through it), the layer solution's own
    indenter: within 5 % for a/h = 0.5 … 2, and at ν = 0.499 as at 0.48 (no locking)."""
    row = layer_point(a_over_h, 1e-3, nu)
    assert abs(row["err"]) < 5.0


def test_thin_layer_converges_under_refinement():
    coarse, fine = (layer_point(0.5, s, 0.48) for s in (1e-3, 5e-4))
    assert abs(fine["err"]) < abs(coarse["err"]) / 2
    assert abs(fine["err"]) < 2.0


def test_contact_conditions_hold_and_compliance_is_reciprocal():
    h, d, R = 3e-3, 3e-4, 6e-3
    body = layer_body(h, 6e-3, 1e-3, 0.3e6, 0.45)
    ball = sphere(R, [0.0, 0.0, h + R - d])
    for geometry in ("rest", "deformed"):
        res = body.solve(ball, geometry=geometry)
        lam = -res.force[:, 2]
        assert (lam >= 0).all() and lam.sum() > 0
        assert res.gap.min() > -1e-7                          # no point inside the sphere
        assert np.abs(res.gap[lam > 1e-9 * lam.max()]).max() < 1e-7  # force only where it touches
    # Maxwell–Betti: W_sd = W_dsᵀ (guards the kept columns' bookkeeping, not the physics)
    p = np.flatnonzero(np.abs(res.force).sum(1) > 0)[:4]
    W = body._columns
    for s, q in itertools.product(p, p):
        assert np.allclose(W[int(q)][s], W[int(s)][q].T, rtol=1e-8, atol=1e-16)
    with pytest.raises(ConfigError, match="geometry"):
        body.solve(ball, geometry="bent")


def test_product_pad_press_is_positive_monotone_and_repeatable():
    from gausstac_maniskill.bench.quasistatic import _pad
    from gausstac_maniskill.bench.pad import _collider, indenter_pose
    from gausstac_maniskill.fem import pad_body
    from gausstac_maniskill.mpm.colliders import signed_distance

    pad = _pad(1e-3)
    body = pad_body(pad)
    assert body.fixed.any(axis=1).sum() > 0
    S = pad.sensor_frame
    forces = []
    for d in (0.25e-3, 0.5e-3, 1e-3):
        col = _collider("sphere", indenter_pose("sphere", S, -d), 0.0)

        def sdf(x, col=col):
            phi, n = signed_distance(col, x)
            return phi.astype(float), n.astype(float)

        first = body.solve(sdf)
        again = body.solve(sdf)  # every column kept: a held step
        assert np.array_equal(first.force, again.force)
        forces.append(-(S[:3, :3].T @ first.total_force)[2])
    assert 0 < forces[0] < forces[1] < forces[2]


def _plate(top):
    return lambda x: (top - x[:, 2], np.tile([0.0, 0.0, -1.0], (len(x), 1)))


def _rollers(layer):
    """The layer's outer faces on rollers too: a homogeneous uniaxial strain under a plate."""
    from gausstac_maniskill.fem import QuasiStaticBody

    nodes = layer.body.nodes
    fixed = layer.fixed.copy()
    fixed[nodes[:, 0] == nodes[:, 0].max(), 0] = True
    fixed[nodes[:, 1] == nodes[:, 1].max(), 1] = True
    return QuasiStaticBody(layer.body, layer.E, layer.nu, fixed, layer.points, layer.point_elements,
                           model=layer.model)


def test_finite_strain_uniaxial_compression_is_exact():
    """20 % uniaxial compression: P_zz = μ λ^(−2/3) (λ − (2 + λ²)/(3λ)) + K ln λ / λ of the
    decoupled Neo-Hookean law (F = diag(1, 1, λ)), which the elements reproduce exactly."""
    E, nu, h, s = 0.26e6, 0.48, 4e-3, 1e-3
    body = _rollers(layer_body(h, 3e-3, s, E, nu, model="neo_hookean"))
    lam = 0.8
    res = body.solve(_plate(lam * h), tol=1e-12, max_iterations=200)
    mu, K = E / (2 * (1 + nu)), E / (3 * (1 - 2 * nu))
    P = mu * lam ** (-2 / 3) * (lam - (2 + lam ** 2) / (3 * lam)) + K * np.log(lam) / lam
    area = (3 * s) ** 2
    assert -res.total_force[2] == pytest.approx(-P * area, rel=1e-6)
    assert res.residual < 1e-6


def test_finite_strain_agrees_with_linear_at_small_strain_and_stiffens_at_large():
    h, E, nu = 4e-3, 0.3e6, 0.48
    forces = {}
    for strain in (0.01, 0.1):
        d = strain * h
        R = (0.5 * h) ** 2 / d
        ball = sphere(R, [0.0, 0.0, h + R - d])
        for model in ("linear", "neo_hookean"):
            body = layer_body(h, max(3 * math.sqrt(R * d), math.sqrt(R * d) + 4 * h), 1e-3, E, nu, model=model)
            forces[strain, model] = -body.solve(ball, geometry="deformed").total_force[2]
    assert forces[0.01, "neo_hookean"] == pytest.approx(forces[0.01, "linear"], rel=0.015)
    assert forces[0.1, "neo_hookean"] > 1.03 * forces[0.1, "linear"]


def test_finite_strain_warm_start_and_a_crushed_layer():
    from gausstac_maniskill.errors import SimulationError

    body = layer_body(2e-3, 3e-3, 1e-3, 0.3e6, 0.45, model="neo_hookean")
    first = body.solve(_plate(1.8e-3))
    again = body.solve(_plate(1.8e-3), warm=first)
    assert again.iterations <= 2
    assert again.total_force[2] == pytest.approx(first.total_force[2], rel=1e-4)
    with pytest.raises(SimulationError, match="layer"):
        body.solve(_plate(-0.5e-3), warm=first)  # the plate below the base: nothing can hold that
