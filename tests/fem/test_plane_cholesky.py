"""Pᵀ K⁻¹ Q by the plane-by-plane Cholesky factor (fem/plane_cholesky.py).

Linear algebra, not physics: each result is checked against a dense solve of the same matrix
(NumPy's LAPACK), an independent route. The physics of the compliance it serves is tested in
test_contact.py and test_equilibrium_pad.py."""
import numpy as np
import pytest
import scipy.sparse as sp

from gausstac_maniskill.fem import layer_body
from gausstac_maniskill.fem.plane_cholesky import inverse_between, inverse_products, lattice_planes


def _dense(K, P, Q):
    return P.toarray().T @ np.linalg.solve(K.toarray(), Q.toarray())


def _chain(sizes, seed=0):
    """A random symmetric positive definite block-tridiagonal K with planes of ``sizes``."""
    rng = np.random.default_rng(seed)
    plane = np.repeat(np.arange(len(sizes)), sizes)
    n = len(plane)
    A = rng.normal(size=(n, n)) * (np.abs(plane[:, None] - plane[None, :]) <= 1)
    K = A @ A.T * (np.abs(plane[:, None] - plane[None, :]) <= 1) + n * np.eye(n)  # diagonally dominant
    return sp.csr_matrix(K), plane


def test_body_loads_match_a_dense_solve():
    body = layer_body(2e-3, 4e-3, 1e-3, 0.3e6, 0.49)  # several planes each way
    rng = np.random.default_rng(1)
    n = body.num_free
    P = body.point_loads(np.arange(body.num_points))
    Q = sp.random(n, 7, density=0.05, random_state=rng, format="csc")  # loads spread over many planes
    Q = Q @ sp.diags([1.0, 1.0, 1.0, 0.0, 1.0, 1.0, 1.0])  # column 3: no load
    K = body._K[body._free][:, body._free]
    W = body.inverse_between(P)
    ref = _dense(K, P, P)
    assert body.num_planes > 2
    np.testing.assert_allclose(W, ref, rtol=0, atol=1e-10 * np.abs(ref).max())
    assert np.array_equal(W, W.T)
    M = body.inverse_between(Q, P)
    ref = _dense(K, Q, P)
    np.testing.assert_allclose(M, ref, rtol=0, atol=1e-10 * np.abs(ref).max())
    assert not M[3].any()


@pytest.mark.parametrize("sizes", [(5,), (4, 6), (3, 5, 4), (2, 3, 4, 5, 6, 7, 3)])
def test_any_number_of_planes(sizes, monkeypatch):
    from gausstac_maniskill.fem import plane_cholesky

    monkeypatch.setattr(plane_cholesky, "PRODUCT_BLOCK", 2)  # the products in several blocks
    monkeypatch.setattr(plane_cholesky, "SYMMETRIC_BLOCK", 3)
    K, plane = _chain(sizes)
    rng = np.random.default_rng(2)
    P = sp.random(len(plane), 6, density=0.3, random_state=rng, format="csc")
    Q = sp.random(len(plane), 4, density=0.3, random_state=rng, format="csc")
    for a, b in ((P, None), (P, Q)):
        ref = _dense(K, a, a if b is None else b)
        np.testing.assert_allclose(inverse_between(K, plane, a, b), ref, rtol=0, atol=1e-12 * np.abs(ref).max())


@pytest.mark.parametrize("sizes", [(4,), (3, 5, 4), (2, 3, 4, 5, 6)])
def test_several_products_in_one_sweep(sizes):
    """Each product of a shared sweep against a dense solve: symmetric pairs, a pair and its
    reverse, a load set used by several products, and one used by none."""
    K, plane = _chain(sizes, seed=3)
    rng = np.random.default_rng(4)
    loads = [sp.random(len(plane), c, density=0.3, random_state=rng, format="csc") for c in (5, 3, 2, 4)]
    pairs = [(0, 0), (1, 0), (0, 1), (2, 2), (1, 2)]
    outs = inverse_products(K, plane, loads, pairs)
    assert len(outs) == len(pairs)
    for out, (i, j) in zip(outs, pairs):
        ref = _dense(K, loads[i], loads[j])
        np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    assert np.array_equal(outs[0], outs[0].T)
    single = inverse_between(K, plane, loads[1], loads[0])
    np.testing.assert_allclose(outs[1], single, rtol=0, atol=1e-13 * np.abs(single).max())
    with pytest.raises(ValueError, match=r"pad: pairs \[\(0, 4\)\] must name load sets 0…3"):
        inverse_products(K, plane, loads, [(0, 4)], name="pad")


def test_bad_matrices_are_refused_by_name():
    K, plane = _chain((3, 3, 3))
    P = sp.identity(9, format="csc")
    far = K.tolil()
    far[0, 8] = far[8, 0] = 0.1  # couples planes 0 and 2
    with pytest.raises(ValueError, match="pad: the stiffness couples unknowns more than one plane apart"):
        inverse_between(far.tocsr(), plane, P, name="pad")
    singular = K.tolil()
    singular[4, :] = 0.0
    singular[:, 4] = 0.0  # an unknown held by nothing
    with pytest.raises(ValueError, match="pad: the stiffness is not positive definite"):
        inverse_between(singular.tocsr(), plane, P, name="pad")


def test_planes_run_along_the_axis_of_the_smallest_planes():
    grid = np.stack(np.meshgrid(np.arange(2), np.arange(3), np.arange(10), indexing="ij"), -1).reshape(-1, 3)
    plane, axis = lattice_planes(grid)
    assert axis == 2 and np.array_equal(plane, grid[:, 2])
    plane, axis = lattice_planes(grid + [0, 0, 5])  # numbered from 0, whatever the origin
    assert axis == 2 and plane.min() == 0 and plane.max() == 9


def test_blas_threads_follow_the_process_share(monkeypatch):
    """A collection worker's share of the CPU (GAUSSTAC_CPU_THREADS) bounds BLAS's threads in
    the sweep; without it, every CPU of the process's affinity set."""
    from threadpoolctl import threadpool_info

    from gausstac_maniskill import backend
    from gausstac_maniskill.fem import plane_cholesky

    seen = []
    real = plane_cholesky._add_product

    def spy(out, Yp, Yq, **k):
        seen.append(max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"))
        real(out, Yp, Yq, **k)

    monkeypatch.setattr(plane_cholesky, "_add_product", spy)
    K, plane = _chain((3, 4, 3))
    P = sp.identity(10, format="csc")
    monkeypatch.setenv("GAUSSTAC_CPU_THREADS", "1")
    inverse_between(K, plane, P)
    assert seen and set(seen) == {1}
    monkeypatch.delenv("GAUSSTAC_CPU_THREADS")
    seen.clear()
    inverse_between(K, plane, P)
    assert set(seen) == {backend.cpu_threads()} and backend.cpu_share() is None
