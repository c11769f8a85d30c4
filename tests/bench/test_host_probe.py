"""bench kernels --probe (bench/host_probe.py): the host's noise, printed as min/median/p90."""
import re

import pytest

from gausstac_maniskill import backend
from gausstac_maniskill.bench.host_probe import probe_host

ROW = re.compile(r"min\s+([\d.]+) ms\s+median\s+([\d.]+)\s+p90\s+([\d.]+)\s+median/min ([\d.]+)")


def test_host_probe_prints_its_four_kernels_in_order(capsys):
    """Guards the probe's bookkeeping (four kernels, each timed, min <= median <= p90 and the
    ratio of the two), not the host: any host passes."""
    if backend.current_arch() != "cpu":
        pytest.skip("the probe measures the CPU host")
    assert probe_host(rounds=5) == 0
    rows = [ROW.search(line) for line in capsys.readouterr().out.splitlines()]
    rows = [r for r in rows if r]
    assert len(rows) == 4
    for r in rows:
        lo, med, p90, ratio = map(float, r.groups())
        assert 0.0 < lo <= med <= p90
        assert ratio == pytest.approx(med / lo, abs=0.01)
