"""bench drive_contact: the pad reaction folded into the hand's drives brings a fingertip
pressed into a spring to the static balance of its drives, at ManiSkill's 100 Hz. The
balance is solved from the finger's Jacobian (checked against SAPIEN's kinematics in
tests/tasks/test_pad_reaction.py); PhysX integrates the motion."""
import numpy as np
import pytest

from gausstac_maniskill.bench.drive_contact import main, press

pytestmark = pytest.mark.sapien


@pytest.mark.parametrize("stiffness", [6.0e3, 1.0e5])
def test_folded_contact_reaches_the_drives_balance(stiffness):
    r = press("fold", tgs=False, iterations=15, stiffness=stiffness, sim_freq=100, seconds=0.5)
    f = r["forces"]
    assert np.all(np.isfinite(f)) and f.min() >= 0.0
    assert r["balance"] > 5.0  # measured 9.83 N and 36.5 N
    assert abs(f[-1] / r["balance"] - 1.0) < 0.01  # measured 0.0 % after 0.2 s
    assert f.max() < 2.0 * r["balance"]  # no overshoot worth the name (measured 1.0x and 1.5x)


def test_bench_prints_its_table(capsys):
    assert main(["--stiffness", "6000"]) == 0
    out = capsys.readouterr().out
    assert "| 6000 | fold | PGS 15 |" in out and "| 6000 | d6 | PGS 255 |" in out
