"""bench patch (cost against pad size and contact area): the scene is sound at a coarse grid."""
from gausstac_maniskill.bench.patch import format_table, run


def test_pad_size_sweep_scales_the_pad_not_the_contact():
    small, large = run(8e-3, 5e-3, 2e-3), run(16e-3, 5e-3, 2e-3)
    assert large["particles"] == 4 * small["particles"]  # the whole awake pad is simulated today
    assert small["Fn"] > 0.5 and large["Fn"] > 0.5  # the sphere pushes the pad down (pad -> sphere +z)
    assert "| 16 | 5 |" in format_table([small, large])
