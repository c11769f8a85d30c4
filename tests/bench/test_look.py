"""bench look: the splat camera's hand lands on SAPIEN's hand (same mesh, pose, camera)."""
import pytest

from gausstac_maniskill.bench.look import compare, format_table


@pytest.mark.sapien
def test_splat_hand_matches_sapien_hand():
    """A misplaced or mis-posed hand (a wrong pose convention, camera or intrinsics) drops the
    open hand's PSNR on SAPIEN's hand pixels far below the measured 18.7 dB, MS-SSIM 0.96."""
    rows, strip = compare((128, 128), gestures=["open"])
    (r,) = rows
    assert r["pixels"] > 500
    assert r["psnr"] > 15.0 and r["msssim"] > 0.9, r
    assert strip.shape == (128, 3 * 128, 3)
    assert "| 128x128 | open |" in format_table(rows)
