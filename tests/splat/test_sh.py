"""Spherical harmonics: the basis, coefficient counts and rotation of coefficients."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.splat.sh import num_sh_coeffs, rotate_sh, sh_basis, sh_degree_from_coeffs
from gausstac_maniskill.transforms import rotation_about


def _directions(n, seed=0):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_basis_matches_the_written_out_reference(sh_basis_reference):
    d = _directions(40)
    for degree in range(4):
        ours = sh_basis(d, degree)
        assert ours.shape == (40, num_sh_coeffs(degree))
        ref = sh_basis_reference(torch.as_tensor(d), degree).numpy()
        assert np.allclose(ours, ref, atol=1e-12)


def test_coefficient_counts():
    assert [num_sh_coeffs(d) for d in range(4)] == [1, 4, 9, 16]
    assert [sh_degree_from_coeffs(k) for k in (1, 4, 9, 16)] == [0, 1, 2, 3]
    with pytest.raises(ConfigError, match="5 SH coefficients"):
        sh_degree_from_coeffs(5)


def test_rotate_sh_matches_rotated_evaluation():
    rng = np.random.default_rng(0)
    R = rotation_about(rng.normal(size=3), 1.1)
    sh = torch.as_tensor(rng.normal(size=(5, 16, 3)))
    out = rotate_sh(sh, R)
    d = _directions(50, seed=1)
    new = np.einsum("mk,nkc->nmc", sh_basis(d, 3), out.numpy())
    old = np.einsum("mk,nkc->nmc", sh_basis(d @ R.T, 3), sh.numpy())
    assert np.abs(new - old).max() < 1e-8
    assert not np.allclose(out.numpy(), sh.numpy())
    assert torch.allclose(out[:, 0], sh[:, 0], atol=1e-12)  # the DC term does not rotate
    with pytest.raises(ConfigError, match="5 SH coefficients"):
        rotate_sh(torch.zeros(2, 5, 3), R)
