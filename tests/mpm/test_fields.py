"""Two velocity fields (multi-field MPM): groups of different fields are separate bodies
that meet through a frictional, non-adhesive contact rule on the grid. The scene is
``bench soft``'s: two free 10 x 8 x 8 mm blocks (100 kPa), 1 mm apart, closing at 0.1 m/s."""
import numpy as np
import pytest

from gausstac_maniskill.bench.soft import collide
from gausstac_maniskill.config import Material, SolverSettings
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.mpm import MPMWorld


def test_two_bodies_bounce_apart_conserving_momentum_without_passing_through():
    r = collide(field_b=1)
    assert np.abs(r["p1"] - r["p0"]).max() < 1e-3 * r["p_block"]  # equal and opposite contact impulses
    assert r["va"] < 0.0 < r["vb"]  # they bounced: no sticking, no adhesion
    assert 0.3 < (r["vb"] - r["va"]) / r["speed"] <= 1.0  # coefficient of restitution (elastic blocks ring)
    # surfaces sit half a spacing beyond the particle centres: touching bodies keep their
    # centres about one spacing apart; the contact test lets them come within 0.8 of it
    assert 0.8 * r["spacing"] < r["closest"] < 1.5 * r["spacing"]


def test_one_field_meets_a_cell_early():
    """What the second field is for: in one field the blocks' B-spline supports overlap and
    they push each other away from over two particle spacings."""
    r = collide(field_b=0)
    assert r["closest"] > 2.0 * r["spacing"]


def test_field_friction_and_contact_radius_are_checked():
    w = MPMWorld(SolverSettings(mass_scaling=1.0, max_substeps=2000))
    with pytest.raises(ConfigError, match="field=2 must be 0 or 1"):
        w.add_group("x", np.zeros((1, 3)), Material(E=3.0e5, nu=0.45, density=1100.0), field=2)
    with pytest.raises(ConfigError, match="contact_radius must be > 0"):
        w.add_group("y", np.zeros((2, 3)), Material(E=3.0e5, nu=0.45, density=1100.0), contact_radius=[1e-3, 0.0])
    with pytest.raises(ConfigError, match="soft_friction"):
        SolverSettings(soft_friction=-0.1, mass_scaling=1.0, max_substeps=2000)
