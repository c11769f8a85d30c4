"""Two velocity fields (multi-field MPM): groups of different fields are separate bodies
that meet through a frictional, non-adhesive contact rule on the grid."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from gausstac_maniskill.config import Material, SolverSettings
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.mpm import MPMWorld, box_particles


def _collide(field_b: int, speed: float = 0.1, steps: int = 12):
    """Two 10 x 8 x 8 mm blocks (100 kPa, ν = 0.3), 1 mm apart, closing at ``speed`` m/s
    without gravity. Returns (velocity of a, of b before and after [m/s], total momentum
    before and after [kg m/s], closest approach of two particles of different blocks [m],
    particle spacing [m])."""
    s = SolverSettings(dx=1e-3, gravity=(0.0, 0.0, 0.0))
    w = MPMWorld(s)
    m = Material(E=1e5, nu=0.3, density=1000.0)
    a = box_particles([-0.0105, -0.004, -0.004], [-0.0005, 0.004, 0.004], s.particle_spacing)
    w.add_group("a", a, m, velocity=[speed / 2, 0, 0])
    w.add_group("b", a + [0.011, 0.0, 0.0], m, velocity=[-speed / 2, 0, 0], field=field_b)
    mass = m.density * s.particle_spacing ** 3

    def momentum():
        return mass * (w.velocities("a").sum(0) + w.velocities("b").sum(0))

    p0, closest = momentum(), np.inf
    for _ in range(steps):
        w.step(1e-3)
        closest = min(closest, cKDTree(w.positions("a")).query(w.positions("b"))[0].min())
    va, vb = w.velocities("a").mean(0)[0], w.velocities("b").mean(0)[0]
    return va, vb, p0, momentum(), closest, s.particle_spacing, mass * len(a) * speed / 2


def test_two_bodies_bounce_apart_conserving_momentum_without_passing_through():
    va, vb, p0, p1, closest, h, p_block = _collide(field_b=1)
    assert np.abs(p1 - p0).max() < 1e-3 * p_block  # the contact impulses are equal and opposite
    assert va < 0.0 < vb  # they bounced: no sticking, no adhesion
    assert 0.3 < (vb - va) / 0.1 <= 1.0  # coefficient of restitution (elastic blocks ring)
    # surfaces sit half a spacing beyond the particle centres: touching bodies keep their
    # centres about one spacing apart; the contact test lets them come within 0.8 of it
    assert 0.8 * h < closest < 1.5 * h


def test_one_field_meets_a_cell_early():
    """What the second field is for: in one field the blocks' B-spline supports overlap and
    they push each other away from over two particle spacings."""
    *_, closest, h, _p = _collide(field_b=0)
    assert closest > 2.0 * h


def test_field_and_friction_are_checked():
    w = MPMWorld(SolverSettings())
    with pytest.raises(ConfigError, match="field=2 must be 0 or 1"):
        w.add_group("x", np.zeros((1, 3)), Material(), field=2)
    with pytest.raises(ConfigError, match="soft_friction"):
        SolverSettings(soft_friction=-0.1)
