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


def test_fem_rows_read_the_same_force_both_ways():
    """Guard (the two rows of a case compare the code with itself): the equilibrium pad read
    from its full compliance and point by point gives the same press, a held step keeps it,
    and the table names both ways. Physics check: the sphere pushes the pad down, and a
    narrow pad reads less force than a wide one under the same press (its free sides let the
    near-incompressible layer bulge out; a wide layer is confined)."""
    from gausstac_maniskill.bench.patch import fem_pad, format_fem_table, run_fem

    by_points = run_fem(fem_pad(8e-3, 2e-3, False), 5e-3)
    full = run_fem(fem_pad(8e-3, 2e-3, True), 5e-3)
    assert by_points["loaded"] == full["loaded"] > 0
    assert abs(by_points["Fn"] - full["Fn"]) < 1e-5 * full["Fn"]
    assert by_points["columns"] >= by_points["loaded"] and full["columns"] == 0
    wide = run_fem(fem_pad(16e-3, 2e-3, True), 5e-3)
    assert wide["Fn"] > full["Fn"] > 0.5
    text = format_fem_table([by_points, full])
    assert "point by point" in text and "all points (W)" in text
