"""``bench motion``: the pads' pseudo-mass against forces read in motion (coarse grid, fast)."""
import math

import pytest

from gausstac_maniskill.bench import motion


def test_extrapolation_to_no_pseudo_mass():
    """F(s) = F0 + c·√s through the two smallest factors gives back F0 (guards the bench's fit)."""
    rows = [dict(mass_scaling=s, **{k: 2.0 + 0.03 * (i + 1) * math.sqrt(s) for i, k in enumerate(motion.FIELDS)})
            for s in (1000.0, 16.0, 250.0)]
    assert motion.extrapolate(rows) == pytest.approx({k: 2.0 for k in motion.FIELDS}, rel=1e-12)


def test_held_force_against_the_pseudo_mass_and_who_moves():
    """The held plate's force at dx = 2 mm is the same at pad pseudo-masses ×62.5 and ×1000
    (within 3 %; measured 1.8 %): the quasi-static hold does not depend on the mass scaling.
    Pressed by the finger instead of the plate, to the same place, it holds 3 % less (measured
    −3.1 % here, −3.0 % at dx = 1 mm extrapolated to no pseudo-mass; the path leaves a state the
    elastic pad should not remember, BENCHMARKS.md). The 6 % bound only guards that known gap from
    growing; it is not evidence of physics. What the pseudo-mass adds while the contact moves is
    measured by ``bench motion``."""
    obj = motion.run(1000.0, dx=2e-3, mover="object", hold=3)
    link = motion.run(1000.0, dx=2e-3, mover="link", hold=3)
    light = motion.run(62.5, dx=2e-3, mover="object", hold=3)
    assert obj["Fn_held"] > 1.0 and obj["Ft_held"] > 0.2
    assert light["Fn_held"] == pytest.approx(obj["Fn_held"], rel=0.03)
    assert link["Fn_held"] == pytest.approx(obj["Fn_held"], rel=0.06)
