"""bench patch (cost against pad size and contact area, with the active patch): the scene is
sound at a coarse grid, and the table pairs each patch run with its whole-pad run."""
from gausstac_maniskill.bench.patch import format_table, run


def test_pad_size_sweep_and_the_patch_row():
    small, large = run(8e-3, 5e-3, 2e-3), run(16e-3, 5e-3, 2e-3)
    assert large["particles"] == large["active"] == 4 * small["particles"]  # the whole pad is simulated
    assert small["Fn"] > 0.5 and large["Fn"] > 0.5  # the sphere pushes the pad down (pad -> sphere +z)
    patched = run(16e-3, 5e-3, 2e-3, 2e-3)
    assert patched["active"] < patched["particles"] == large["particles"]
    text = format_table([small, large, patched])
    assert "| 16 | 5 |" in text
    assert f"{100 * (patched['Fn'] / large['Fn'] - 1):+.1f}%" in text.splitlines()[-1]
