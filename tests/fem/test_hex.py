"""Cube elements: rigid modes, no spurious modes, the patch test, the elimination order."""
import numpy as np
import pytest
import scipy.sparse.linalg as sla

from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.fem import element_stiffness, layer_body, stiffness, voxel_body
from gausstac_maniskill.fem.hex import dissection_order


@pytest.mark.parametrize("nu", [0.3, 0.48, 0.499])
def test_element_has_six_rigid_modes_and_no_spurious_one(nu):
    K = element_stiffness(1e-3, 0.26e6, nu)
    assert np.allclose(K, K.T)
    w = np.linalg.eigvalsh(K)
    # 3 translations + 3 rotations carry no energy; any further zero mode would be an
    # hourglass mode of the reduced integration (the deviatoric part is fully integrated)
    assert np.all(np.abs(w[:6]) < 1e-9 * w[-1])
    assert w[6] > 1e-5 * w[-1]  # the softest shear mode against the bulk mode: μ/K ≈ 2e-3 at ν = 0.499


def test_uniaxial_strain_is_exact():
    """A layer compressed by a flat frictionless plate between rollers (uniaxial strain) carries
    σ = M ε with the oedometer modulus M = E(1 − ν)/((1 + ν)(1 − 2ν)), at any element count."""
    from gausstac_maniskill.fem import QuasiStaticBody

    E, nu, h, s = 0.3e6, 0.48, 4e-3, 1e-3
    layer = layer_body(h, 5e-3, s, E, nu)
    nodes = layer.body.nodes
    fixed = layer.fixed.copy()
    fixed[nodes[:, 0] == nodes[:, 0].max(), 0] = True
    fixed[nodes[:, 1] == nodes[:, 1].max(), 1] = True
    body = QuasiStaticBody(layer.body, E, nu, fixed, layer.points, layer.point_elements)
    d = 1e-3 * h
    res = body.solve(lambda x: ((h - d) - x[:, 2], np.tile([0.0, 0.0, -1.0], (len(x), 1))))
    M = E * (1 - nu) / ((1 + nu) * (1 - 2 * nu))
    width = nodes[:, 0].max() * s
    assert -res.total_force[2] == pytest.approx(M * d / h * width ** 2, rel=1e-9)
    assert np.allclose(res.displacement[:, 2], -d, rtol=1e-9)


def test_dissection_order_factor_solves_the_system():
    layer = layer_body(2e-3, 3e-3, 5e-4, 0.3e6, 0.45)
    order = dissection_order(layer.body.nodes, leaf=8)
    assert np.array_equal(np.sort(order), np.arange(len(layer.body.nodes)))
    K = stiffness(layer.body, 0.3e6, 0.45)
    free = np.flatnonzero(~layer.fixed.ravel())
    rng = np.random.default_rng(0)
    f = rng.normal(size=len(free))
    u = layer.nodal_displacement(np.arange(3), rng.normal(size=(3, 3)))  # exercises the factor
    assert np.isfinite(u).all()
    ref = sla.spsolve(K[free][:, free].tocsc(), f)
    # the body's factor, in its own elimination order, solves the same system
    rows = layer._row[free]
    b = np.empty(len(free))
    b[rows] = f
    got = layer._lu.solve(b)[rows]
    assert np.allclose(got, ref, rtol=1e-8, atol=1e-12 * np.abs(ref).max())


def test_cut_cells_full_are_whole_cubes_and_neo_hookean_linearises_to_them():
    """Cut cells (``fill``): full ones assemble the whole cubes' stiffness to rounding (each
    sub-cell integrated exactly); with any fill, the finite-strain forces linearise to the cut
    stiffness exactly (their finite-strain part is added to it), their empty sub-cells stay
    linear, and an element that is half empty is about half as stiff."""
    from gausstac_maniskill.fem.hex import neo_hookean_forces

    E, nu = 0.26e6, 0.48
    vox = np.stack(np.meshgrid(range(3), range(3), range(2), indexing="ij"), -1).reshape(-1, 3)
    whole = voxel_body(vox, np.zeros(3), 1e-3)
    full = voxel_body(vox, np.zeros(3), 1e-3, fill=np.ones((len(vox), 64)))
    K0, K1 = stiffness(whole, E, nu), stiffness(full, E, nu)
    assert abs(K1 - K0).max() < 1e-12 * abs(K0).max()
    rng = np.random.default_rng(1)
    cut = voxel_body(vox, np.zeros(3), 1e-3, fill=rng.uniform(0.0, 2.0, (len(vox), 64)) + 1e-4)
    K = stiffness(cut, E, nu)
    u = rng.normal(size=(len(cut.nodes), 3)) * 1e-9
    f = neo_hookean_forces(cut, u, E, nu).ravel()
    assert np.abs(f - K @ u.ravel()).max() < 1e-4 * np.abs(K @ u.ravel()).max()  # strain 1e-6: exact to O(ε)
    # the empty parts (fill 1e-4) stay linear: material in the bottom half of each cube, a
    # top corner pushed 2.5 mm across its cube turns the cube's top inside out, not its bottom
    bottom = voxel_body(vox, np.zeros(3), 1e-3, fill=np.where(np.arange(64) % 4 < 2, 1.0, 1e-4)[None].repeat(len(vox), 0))
    far = np.zeros((len(bottom.nodes), 3))
    far[np.flatnonzero((bottom.nodes[:, 2] == 2) & (bottom.nodes[:, 0] == 0))[0], 0] = 2.5e-3
    assert np.isfinite(neo_hookean_forces(bottom, far, E, nu)).all()
    with pytest.raises(FloatingPointError):  # the whole cubes invert
        neo_hookean_forces(full, far, E, nu)
    one = voxel_body([[0, 0, 0]], np.zeros(3), 1e-3)
    half_fill = np.where(np.arange(64) < 32, 1.0, 0.0)[None]  # the lower half (x < ½) of the cube
    half = voxel_body([[0, 0, 0]], np.zeros(3), 1e-3, fill=half_fill)
    ratio = np.trace(stiffness(half, E, nu).toarray()) / np.trace(stiffness(one, E, nu).toarray())
    assert 0.4 < ratio < 0.6
    with pytest.raises(ConfigError, match="fill"):
        voxel_body(vox, np.zeros(3), 1e-3, fill=np.ones((len(vox), 10)))
    with pytest.raises(ConfigError, match="fill"):
        voxel_body(vox, np.zeros(3), 1e-3, fill=np.zeros((len(vox), 8)))


@pytest.mark.parametrize("fill", [None, 0.75])
def test_neo_hookean_forces_of_a_homogeneous_deformation_are_its_stress(fill):
    """An affine displacement u = (F − I) X of a 2×2×2 block: the nodal forces on the face
    x = max add up to P e_x times its area, P the decoupled Neo-Hookean law's first Piola stress
    μ J^(−2/3) (F − tr(FᵀF)/3 F⁻ᵀ) + K ln J F⁻ᵀ (any integration rule is exact for a constant F).
    Whole cubes take their Gauss points; cut cubes ¾ full everywhere their sub-cell centres,
    which must carry ¾ of it."""
    from gausstac_maniskill.fem.hex import neo_hookean_forces

    E, nu, s = 0.26e6, 0.48, 1e-3
    vox = np.stack(np.meshgrid(range(2), range(2), range(2), indexing="ij"), -1).reshape(-1, 3)
    body = voxel_body(vox, np.zeros(3), s, fill=None if fill is None else np.full((len(vox), 64), fill))
    F = np.array([[0.9, 0.1, 0.0], [0.0, 1.05, -0.05], [0.02, 0.0, 0.85]])
    X = body.nodes * s
    f = neo_hookean_forces(body, X @ (F - np.eye(3)).T, E, nu)
    mu, K = E / (2 * (1 + nu)), E / (3 * (1 - 2 * nu))
    J = np.linalg.det(F)
    Finv_T = np.linalg.inv(F).T
    P = mu * J ** (-2 / 3) * (F - np.trace(F.T @ F) / 3 * Finv_T) + K * np.log(J) * Finv_T
    face = body.nodes[:, 0] == body.nodes[:, 0].max()
    expected = (1.0 if fill is None else fill) * P[:, 0] * (2 * s) ** 2
    assert np.allclose(f[face].sum(0), expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
    assert np.abs(f.sum(0)).max() < 1e-9 * np.abs(expected).max()  # in equilibrium as a whole


def test_bad_input_names_the_field():
    with pytest.raises(ConfigError, match="nu"):
        element_stiffness(1e-3, 0.3e6, 0.5)
    with pytest.raises(ConfigError, match="twice"):
        voxel_body([[0, 0, 0], [0, 0, 0]], np.zeros(3), 1e-3)
    with pytest.raises(ConfigError, match="whole number"):
        layer_body(4e-3, 5e-3, 1.5e-3, 0.3e6, 0.45)
