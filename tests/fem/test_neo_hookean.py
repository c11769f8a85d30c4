"""The finite-strain remainder's two evaluations: the Taichi kernel (Taichi on the CPU) and the
NumPy sums (Taichi on CUDA, where the kernel aborted). Code against code: this guards that the
two stay the same law, and that the kernel's sums repeat to the bit; the law itself is checked against the Neo-Hookean stress in
tests/fem/test_hex.py and tests/fem/test_contact.py."""
import numpy as np
import pytest

from gausstac_maniskill import backend
from gausstac_maniskill.fem import voxel_body
from gausstac_maniskill.fem.hex import _moduli, strain_points
from gausstac_maniskill.fem.neo_hookean import remainder_forces, remainder_forces_numpy


def test_kernel_and_numpy_sums_agree_on_whole_and_cut_cubes():
    if backend.ensure_init() != "cpu":
        pytest.skip("the kernel runs on Taichi's CPU only")
    rng = np.random.default_rng(3)
    vox = np.stack(np.meshgrid(range(4), range(3), range(2), indexing="ij"), -1).reshape(-1, 3)
    share = np.where(np.arange(len(vox)) % 3 == 0, 0.3, 0.8)[:, None]  # a third of the cubes under half full: linear
    fill = np.where(rng.uniform(size=(len(vox), 64)) < share, 1.0, 1e-4)
    fill[1:3] = 1.0  # whole cubes: Gauss points
    body = voxel_body(vox, np.zeros(3), 1e-3, fill=fill)
    points = strain_points(body)
    assert {-1, 0, 1} <= set(points.rule.tolist())  # every rule is exercised
    mu, bulk = _moduli(0.26e6, 0.48)
    u = rng.normal(size=(len(body.nodes), 3)) * 4e-5  # strains of several per cent
    got, ref = remainder_forces(points, u, mu, bulk), remainder_forces_numpy(points, u, mu, bulk)
    assert np.abs(ref).max() > 1e-3
    assert np.allclose(got, ref, rtol=0.0, atol=1e-12 * np.abs(ref).max())
    assert np.array_equal(remainder_forces(points, u, mu, bulk), got)  # a run repeats to the bit
    crushed = u.copy()
    crushed[body.element_nodes[0, 7]] = [-2e-3, -2e-3, -2e-3]  # a whole cube's corner through its opposite one
    for evaluate in (remainder_forces, remainder_forces_numpy):
        with pytest.raises(FloatingPointError, match="inverted"):
            evaluate(points, crushed, mu, bulk)
