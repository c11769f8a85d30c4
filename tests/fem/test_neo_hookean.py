"""The finite-strain remainder's two evaluations: the Taichi kernel (Taichi on the CPU) and the
torch sums (Taichi on CUDA, where the kernel aborts: there both sides are torch, on the GPU and
on the CPU). Code against code: this guards that the two stay the same law, and that the sums
repeat to the bit; the law itself is checked against the Neo-Hookean stress in
tests/fem/test_hex.py and tests/fem/test_contact.py."""
import numpy as np
import pytest

from gausstac_maniskill.fem import voxel_body
from gausstac_maniskill.fem.hex import _moduli, strain_points
from gausstac_maniskill.fem.neo_hookean import remainder_forces, remainder_forces_torch


def test_kernel_and_torch_sums_agree_on_whole_and_cut_cubes():
    rng = np.random.default_rng(3)
    vox = np.stack(np.meshgrid(range(4), range(3), range(2), indexing="ij"), -1).reshape(-1, 3)
    share = np.where(np.arange(len(vox)) % 3 == 0, 0.3, 0.8)[:, None]  # a third of the cubes under half full: linear
    fill = np.where(rng.uniform(size=(len(vox), 64)) < share, 1.0, 1e-4)
    fill[1:3] = 1.0  # whole cubes: Gauss points
    body = voxel_body(vox, np.zeros(3), 1e-3, fill=fill)
    points = strain_points(body)
    assert {-1, 0} <= set(points.rule.tolist())  # both rules are exercised
    mu, bulk = _moduli(0.26e6, 0.48)
    u = rng.normal(size=(len(body.nodes), 3)) * 4e-5  # strains of several per cent
    got, ref = remainder_forces(points, u, mu, bulk), remainder_forces_torch(points, u, mu, bulk)
    assert np.abs(ref).max() > 1e-3
    assert np.allclose(got, ref, rtol=0.0, atol=1e-12 * np.abs(ref).max())
    assert np.array_equal(remainder_forces(points, u, mu, bulk), got)  # a run repeats to the bit
    crushed = u.copy()
    crushed[body.element_nodes[0, 7]] = [-2e-3, -2e-3, -2e-3]  # a whole cube's corner through its opposite one
    for evaluate in (remainder_forces, remainder_forces_torch):
        with pytest.raises(FloatingPointError, match="inverted"):
            evaluate(points, crushed, mu, bulk)


@pytest.mark.parametrize("n, left, right", [(4, 1 / 8, 0.0), (3, 1 / 8, 1 / 24)])
def test_a_cut_cube_weighs_its_gauss_points_by_the_material_of_their_octants(n, left, right):
    """The quadrature of a cut cube's remainder: each Gauss point weighs the material in its octant
    (a sub-cell on a mid-plane, odd n, split evenly between the octants it lies in). A 1 mm cube
    filled on its x < 0 side (and, for n = 3, its middle layer) weighs each x < 0 point ``left``
    mm³ and each x > 0 point ``right`` mm³; the weights sum to the material's volume."""
    from gausstac_maniskill.fem.hex import CORNERS, subcell_points

    xi = subcell_points(n)
    fill = np.where(xi[:, 0] <= 0.0, 1.0, 1e-4)
    body = voxel_body(np.zeros((1, 3), int), np.zeros(3), 1e-3, fill=fill[None])
    points = strain_points(body)
    assert points.rule.tolist() == [0]
    expected = np.where(CORNERS[:, 0] == 0, left, right) * 1e-9  # [m³]
    assert np.allclose(points.weight[0], expected, rtol=1e-12, atol=0.0)
    assert points.centre_weight[0] == pytest.approx((fill >= 0.5).mean() * 1e-9, rel=1e-12)
