"""The pad convergence benchmark: its numerical helpers and one very coarse end-to-end run."""
import math

import numpy as np
import pytest

from gausstac_maniskill.bench import pad as bench


@pytest.mark.parametrize("h", [(0.5e-3, 1e-3, 2e-3), (0.5e-3, 0.75e-3, 1e-3), (2e-3, 0.5e-3, 1.25e-3)])
@pytest.mark.parametrize("p, C", [(2.0, 3e5), (1.0, -40.0), (0.7, 5.0)])
def test_richardson_recovers_order_and_limit(h, p, C):
    f = [4.2 + C * x ** p for x in h]
    r = bench.richardson(h, f)
    assert r["status"] == "ok"
    assert r["p"] == pytest.approx(p, rel=1e-6)
    assert r["f_star"] == pytest.approx(4.2, rel=1e-6)


def test_richardson_not_monotone_and_not_converging():
    for f in ([1.0, 1.2, 1.1], [1.0, 1.0, 1.3]):
        r = bench.richardson([0.5e-3, 0.75e-3, 1e-3], f)
        assert r == {"p": None, "f_star": None, "status": "not monotone"}
    # differences growing as h shrinks: a negative order, no extrapolated value
    r = bench.richardson([0.5e-3, 1e-3, 2e-3], [1.0, 2.0, 2.5])
    assert r["status"] == "not converging" and r["p"] == pytest.approx(-1.0) and r["f_star"] is None


def test_rel_l2():
    ref = np.arange(32.0).reshape(4, 4, 2)
    assert bench.rel_l2(ref, ref) == 0.0
    assert bench.rel_l2(1.1 * ref, ref) == pytest.approx(0.1)
    assert bench.rel_l2(ref + 1.0, ref) == pytest.approx(math.sqrt(32) / np.linalg.norm(ref))
    assert math.isnan(bench.rel_l2(ref, np.zeros_like(ref)))


def test_coarse_press_and_slide(tmp_path):
    depths = (0.5e-3, 1.0e-3)
    cases = bench.run([2e-3, 1.5e-3], ("plate",), depths, protocol=bench.Protocol(press=2, slide=1, hold=2),
                      progress=False)
    lay = bench.index_spec().layout
    assert [c["dx"] for c in cases] == [2e-3, 1.5e-3]
    for c in cases:
        assert [(ph["phase"], ph["d"]) for ph in c["phases"]] == [(p, d) for d in depths for p in ("press", "slide")]
        assert c["substeps"] > 0 and c["step_ms"] > 0
        for ph in c["phases"]:
            assert ph["maps"]["depth"].shape == ph["maps"]["force"].shape == (lay.rows, lay.cols)
            assert ph["maps"]["shear"].shape == (lay.rows, lay.cols, 2)
            assert all(np.isfinite(m).all() for m in ph["maps"].values())
            assert all(np.isfinite(ph[k]) for k in ("Fn", "Ft", "F_map", "peak_depth", "area_taxel", "area_particle"))
            assert ph["Fn"] > 0 and ph["area_particle"] > 0 and ph["peak_depth"] > 0
            # the force map adds up to the indenter's reaction (same contact forces, sensor axis)
            assert ph["F_map"] == pytest.approx(ph["Fn"], rel=0.05, abs=1e-3)
        press = {ph["d"]: ph for ph in c["phases"] if ph["phase"] == "press"}
        assert press[1.0e-3]["Fn"] > 1.3 * press[0.5e-3]["Fn"]
        assert press[1.0e-3]["peak_depth"] > press[0.5e-3]["peak_depth"]
        slide = [ph for ph in c["phases"] if ph["phase"] == "slide"]
        assert all(ph["Ft"] > 0 for ph in slide)  # friction resists the slide along +x
    ana = bench.analyse(cases, default_dx=2e-3)
    assert ana["verdict"].startswith(("PASS", "FAIL"))
    assert {r["status"] for r in ana["richardson"]} == {"fewer than 3 grids"}
    assert all(ph["l2"]["depth"] == 0.0 for ph in cases[1]["phases"])  # the finest run is the reference
    text = bench.format_tables(cases, ana, 2e-3)
    assert "| plate | 1 | slide | 1.5 |" in text and ana["verdict"] in text
    assert len(bench.plot_maps(cases, str(tmp_path))) in (0, 4)


def _fake_case(fn):
    """run_case stand-in: Fn = fn(dx, mass_scaling); guards speed_curve's bookkeeping, not physics."""
    def run_case(dx, indenter, depths, protocol=None, bar=None, mass_scaling=None, **_):
        return dict(particles=int(1e-6 / dx ** 3), active=0.5e-6 / dx ** 3, cfl=0.4, substeps=10.0, step_ms=1e-3 / dx,
                    spacing=0.5 * dx,
                    phases=[dict(Fn=0.5 * fn(dx, mass_scaling), Fn_end=fn(dx, mass_scaling), F_spread=0.0,
                                 F_stress=0.5 * fn(dx, mass_scaling), F_stress_end=0.95 * fn(dx, mass_scaling),
                                 F_pressure=0.5 * fn(dx, mass_scaling), F_pressure_end=0.9 * fn(dx, mass_scaling),
                                 wall_end=0.5e-3 / dx, substeps_end=5.0)])
    return run_case


def test_speed_curve_reference_and_errors(monkeypatch):
    # first-order convergence to 2 N: the reference is the Richardson limit, not the finest run
    monkeypatch.setattr(bench, "run_case", _fake_case(lambda dx, ms: 2.0 + 100.0 * dx + (0.1 if ms > 1e3 else 0.0)))
    pts = [(2e-3, 1e3, None), (1e-3, 1e3, None), (0.5e-3, 1e3, None), (1e-3, 4e3, None), (1e-3, 1e3, 6e-3)]
    curve = bench.speed_curve(pts, progress=False)
    assert curve["reference"] == pytest.approx(2.0, rel=1e-6)
    assert "Richardson" in curve["reference_from"]
    err = {(r["dx"], r["mass_scaling"]): r["err"] for r in curve["runs"]}
    assert err[(1e-3, 1e3)] == pytest.approx(0.05) and err[(1e-3, 4e3)] == pytest.approx(0.1)
    assert sum(r["patch_radius"] == 6e-3 for r in curve["runs"]) == 1  # a patch run is not the reference
    assert "| 6 |" in bench.format_curve(curve, "sphere", 1e-3)
    table = bench.format_curve(curve, "sphere", 1e-3)
    assert table.count("\n| ") == 1 + len(pts) and "-5.0%" in table  # header + one row per point
    # the pad at equilibrium: its own columns (elements), none of the MPM's (pseudo-mass, substeps)
    fem = bench.format_curve(bench.speed_curve(pts[:3], progress=False, pad_solver="fem"), "sphere", 1e-3)
    assert "| 1 | 0.5 | 8 |" in fem and "mass scaling" not in fem and "substeps" not in fem
    # no usable order (not monotone): the finest run is the reference
    monkeypatch.setattr(bench, "run_case", _fake_case(lambda dx, ms: {2e-3: 1.0, 1e-3: 1.3, 0.5e-3: 1.2}[dx]))
    curve = bench.speed_curve(pts[:3], progress=False)
    assert curve["reference"] == 1.2 and curve["reference_from"].startswith("finest run")
