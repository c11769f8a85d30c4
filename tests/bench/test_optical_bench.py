"""bench optical against the real GelSight frames, on a small gel and its first frame: the simulated
press matches each frame's contact radius and is nearer the real image in the touch's disc than
the no-contact frame is (real sensor data; BENCHMARKS.md has the full 48 frames at the default)."""
import numpy as np

from gausstac_maniskill.bench.optical_frames import compare_frames, frame_metrics, real_frames, summary_lines


def test_a_real_frame_on_a_small_gel():
    result = compare_frames("gelsight", element=0.25e-3, half_width=4e-3, limit=1, progress=False)
    assert len(result["rows"]) == 1
    for row in result["rows"]:
        assert abs(row["sim_radius_px"] - row["radius_px"]) < 1.0
        assert row["sim_psnr_disc"] > row["f0_psnr_disc"] + 5  # dB
        assert 0.5 < row["depth_mm"] < 2.0 and row["force_n"] > 0
    text = "\n".join(summary_lines(result, "gelsight", "linear"))
    assert "press_sphere (linear)" in text and "no-contact frame" in text


def test_metrics_of_a_frame_against_itself():
    data = real_frames("gelsight")
    real, c, r = data["imgs"][0], data["centres"][0], data["radii"][0]
    m = frame_metrics(real, real, c, r)
    assert m["ssim_disc"] == 1.0 and m["psnr_disc"] > 100
    noisy = np.clip(real.astype(int) + 8, 0, 255).astype(np.uint8)
    assert frame_metrics(noisy, real, c, r)["psnr_disc"] < 31
