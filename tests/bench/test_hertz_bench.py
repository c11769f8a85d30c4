"""The Poisson-ratio sweep of ``bench hertz --nu`` (command line, table, file), at a coarse grid."""
import re

from gausstac_maniskill.bench import hertz


def test_nu_sweep_command_writes_its_table(tmp_path, capsys):
    """Guards the sweep's plumbing at dx = 2 mm (a = 1.1 cells: a smoke run, not the benchmark's
    accuracy): one row per ν, a force near Sneddon's, and the summary line in the file."""
    assert hertz.main(["--nu", "0.45", "--dx", "2e-3", "--arch", "cpu", "--out", str(tmp_path)]) == 0
    text = (tmp_path / "nu_sweep.md").read_text()
    assert text in capsys.readouterr().out
    rows = [line for line in text.splitlines() if line.startswith("| 0.45 | F-bar |")]
    assert len(rows) == 1
    cells = [c.strip() for c in rows[0].strip("|").split("|")]
    F_sim, F_sneddon = float(cells[5]), float(cells[6])
    assert 0.7 * F_sneddon < F_sim < 1.4 * F_sneddon
    assert re.search(r"F-bar: max \|err\| against Sneddon [\d.]+ % \(at ν = 0.45", text)
