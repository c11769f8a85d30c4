"""Accuracy against Hertz contact theory, at a coarse resolution (fast)."""
import math

import numpy as np
import pytest

from gausstac_maniskill import reference
from gausstac_maniskill.bench import hertz


@pytest.fixture(scope="module")
def coarse_case():
    # dx = 1 mm: 47k particles, quarter-symmetric pad 10·a_max wide and thick.
    return hertz.run_case(1.0e-3, depths=(0.5e-3, 1.0e-3, 1.5e-3), progress=False)


def test_force_matches_hertz_at_coarse_resolution(coarse_case):
    # Measured at dx = 1 mm: +6.2 %, +1.0 %, -4.7 %. Tolerance 10 %.
    for row in coarse_case["rows"]:
        rel = row["F_sim"] / row["F_hertz"] - 1.0
        assert abs(rel) < 0.10, f"d={row['d']:.4f} m: F={row['F_sim']:.4f} N vs Hertz {row['F_hertz']:.4f} N"


def test_force_is_monotone_in_depth(coarse_case):
    forces = [r["F_sim"] for r in coarse_case["rows"]]
    assert all(b > a for a, b in zip(forces, forces[1:])), forces


def test_contact_radius_within_one_particle_spacing(coarse_case):
    h = coarse_case["h"]
    for row in coarse_case["rows"]:
        assert abs(row["a_sim"] - row["a_hertz"]) < h, (row["a_sim"], row["a_hertz"], h)


def test_pressure_profile_shape(coarse_case):
    # Centre pressure is the largest and the profile vanishes outside ~a.
    row = coarse_case["rows"][-1]
    r = np.array(row["profile_r"])
    p = np.array(row["profile_p"])
    a = row["a_hertz"]
    inner = p[r < 0.5 * a].mean()
    outer = p[r > 1.15 * a].mean() if np.any(r > 1.15 * a) else 0.0
    assert inner > 0.6 * row["p0"]
    assert outer < 0.1 * row["p0"]
    assert row["p_rmse"] < 0.3


def test_hertz_reference_formulas():
    # Sneddon's exact sphere solution tends to Hertz for small a/R.
    F_s, a_s = reference.sneddon(1.0, 1.0, 1e-6)
    assert math.isclose(F_s, reference.hertz_force(1.0, 1.0, 1e-6), rel_tol=1e-3)
    assert math.isclose(a_s, 1e-3, rel_tol=1e-3)
