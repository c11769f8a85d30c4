"""bench look: the splat camera's hand lands on SAPIEN's hand (same mesh, pose, camera)."""
import pytest

from gausstac_maniskill.bench.look import compare, format_table


@pytest.mark.sapien
def test_splat_hand_matches_sapien_hand():
    """A misplaced or mis-posed hand (a wrong pose convention, camera or intrinsics) drops the
    open hand's PSNR on SAPIEN's hand pixels far below the measured 18.7 dB / MS-SSIM 0.962
    (baked colours) and 21.0 dB / 0.978 (shaded with the scene's lights, the default). Shading
    must keep its lead over the baked colours."""
    rows, strip = compare((128, 128), gestures=["open"], timing=False)
    (r,) = rows
    assert r["pixels"] > 500
    assert r["baked"]["psnr"] > 15.0 and r["baked"]["msssim"] > 0.9, r
    assert r["scene"]["psnr"] > 19.5 and r["scene"]["msssim"] > 0.95, r
    assert r["scene"]["psnr"] > r["baked"]["psnr"], r
    assert strip.shape == (128, 5 * 128, 3)
    assert "| 128x128 | open |" in format_table(rows)
