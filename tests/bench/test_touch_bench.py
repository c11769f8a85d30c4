"""``bench touch``: the with/without-touch behaviour-cloning study, run tiny (2 PressCube demos at dx = 3 mm,
2 epochs, 2 evaluation seeds): the pipeline runs end to end, the live observation equals the recorded one, and
the two policies' inputs differ by the tactile vector alone."""
import json

import numpy as np
import pytest

from gausstac_maniskill.bench import touch

ENV = "GaussTac-PressCube-v1"


def test_wilson_interval():
    assert touch.wilson(0, 50)[0] == 0.0 and touch.wilson(50, 50)[1] == 1.0
    lo, hi = touch.wilson(25, 50)
    assert lo == pytest.approx(0.366, abs=1e-3) and hi == pytest.approx(0.634, abs=1e-3)


def test_variant_columns_differ_by_the_tactile_part_only():
    cols = {"agent/qpos": (0, 16), "extra/slide_distance": (16, 17), "extra/slid": (17, 18), "tactile": (18, 274)}
    slide = "GaussTac-SlideCube-v1"
    with_t = touch.variant_index(cols, touch.variant_keys(slide, cols, "touch"))
    without = touch.variant_index(cols, touch.variant_keys(slide, cols, "no_touch"))
    assert list(without) == list(range(17))                    # slid (contact-derived) left out of both
    assert list(with_t) == list(without) + list(range(18, 274))
    assert touch.variant_keys(slide, cols, "full") == list(cols)
    assert touch.variants_of(ENV) == ("touch", "no_touch")


def test_touch_bench_smoke(tmp_path):
    out, png = tmp_path / "touch", tmp_path / "touch.png"
    rc = touch.main(["--tasks", "press", "--demos", "2", "--epochs", "2", "--eval-seeds", "2", "--train-seeds", "1",
                     "--procs", "1", "--mpm-dx", "3e-3", "--out", str(out), "--plot", str(png), "--no-progress"])
    assert rc == 0 and png.stat().st_size > 0
    res = json.loads((out / "touch.json").read_text())["tasks"][ENV]
    assert res["demos"] == 2 and res["env_kwargs"]["mpm_dx"] == 3e-3
    assert res["live_check"]["equal"], res["live_check"]
    assert set(res["variants"]) == {"touch", "no_touch"}
    for v in res["variants"].values():
        assert v["episodes"] == 2 and 0.0 <= v["rate"] <= 1.0
    # the two variants' vectors: no_touch is touch without its tactile columns, in the same order
    from gausstac_maniskill.obs_wrappers import load_demos

    data = load_demos(res["demo_path"], rgb=False, pool=4)
    cols = touch.state_columns(res["demo_path"], 4)
    a = data["state"][:, touch.variant_index(cols, res["variants"]["touch"]["keys"])]
    b = data["state"][:, touch.variant_index(cols, res["variants"]["no_touch"]["keys"])]
    D = res["tactile_dim"]
    assert D == 256 and a.shape[1] == b.shape[1] + D
    assert np.array_equal(a[:, :-D], b) and np.array_equal(a[:, -D:], data["tactile"])
    assert res["variants"]["touch"]["keys"] == res["variants"]["no_touch"]["keys"] + ["tactile"]
    assert np.abs(data["tactile"]).max() > 0  # the demos touch the cube
