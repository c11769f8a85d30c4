"""The optical sensor's image and markers from a prescribed gel surface (no solver involved):
what they guard is the lookup's sign and geometry conventions, and the calibration's errors."""
import json
import shutil

import numpy as np
import pytest
import torch

from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.optical import load_calibration, marker_positions, preset, render_rgb, shading


@pytest.fixture(scope="module", params=["gelsight", "gelsight_mini"])
def sensor(request):
    return preset(request.param).at_resolution(320, 240)


def _bump(sensor, depth=0.5e-3, radius=1.5e-3, centre=(160.0, 120.0)):
    cam = sensor.camera
    yy, xx = np.mgrid[:cam.height, :cam.width].astype(float)
    r2 = ((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2) * (cam.mm_per_px * 1e-3) ** 2
    return torch.tensor(depth * np.exp(-r2 / radius ** 2), dtype=torch.float32)[None]


def test_undeformed_gel_renders_as_its_no_contact_frame():
    s = preset("gelsight_mini")
    img = render_rgb(torch.zeros(2, s.camera.height, s.camera.width), s)
    assert img.dtype == torch.uint8 and img.shape == (2, 480, 640, 3)
    assert torch.equal(img[0], torch.from_numpy(np.array(s.calibration.background)))


def test_indentation_shades_opposite_sides_oppositely(sensor):
    """A bump pressed towards the camera tilts its two flanks opposite ways: the lookup's colour
    change differs between them, and vanishes far from it."""
    d = shading(_bump(sensor), sensor)[0]
    left, right = d[120, 160 - 25], d[120, 160 + 25]
    top, bottom = d[120 - 25, 160], d[120 + 25, 160]
    assert (left - right).abs().max() > 0.05 and (top - bottom).abs().max() > 0.05
    assert d[5, 5].abs().max() < 1e-6  # flat far away: exactly the no-contact frame
    # a dent (pushed away from the camera) tilts each flank the other way: its left flank shades
    # as the bump's right one does, not as its left
    dent = shading(-_bump(sensor), sensor)[0]
    assert (dent[120, 135] - right).abs().max() < 0.5 * (dent[120, 135] - left).abs().max()
    assert (dent[95, 160] - bottom).abs().max() < 0.5 * (dent[95, 160] - top).abs().max()


def test_markers_follow_a_prescribed_shear(sensor):
    cam = sensor.camera
    B = 2
    shear = torch.zeros(B, cam.height, cam.width, 2)
    shear[1, ..., 0] = 0.3e-3  # 0.3 mm along the columns
    shear[1, ..., 1] = -0.1e-3
    rest, moved = marker_positions(shear, torch.zeros(B, cam.height, cam.width), sensor)
    assert moved.shape == (B, len(rest), 2) and len(rest) > 20
    assert torch.allclose(moved[0], rest, atol=1e-4)
    px = 1e3 / cam.mm_per_px
    assert torch.allclose(moved[1] - rest, torch.tensor([0.3e-3 * px, -0.1e-3 * px]), atol=1e-3)
    # a push towards the camera spreads the markers away from the image centre
    _, pushed = marker_positions(torch.zeros_like(shear), torch.full((B, cam.height, cam.width), 1e-3), sensor)
    centre = torch.tensor([(cam.width - 1) / 2, (cam.height - 1) / 2])
    assert ((pushed[0] - centre).norm(dim=1) >= (rest - centre).norm(dim=1) - 1e-4).all()
    # and the dots are drawn dark where they are
    img = render_rgb(torch.zeros(1, cam.height, cam.width), sensor, markers=moved[1:]).float()
    bare = render_rgb(torch.zeros(1, cam.height, cam.width), sensor).float()
    c, r = moved[1, 0].round().long()
    assert (img[0, r, c] < 0.5 * bare[0, r, c]).all()


@pytest.mark.parametrize("broken", ["params.json", "polycalib.npz", "dataPack.npz", "bad_json", "bad_poly"])
def test_a_broken_calibration_folder_names_its_file(tmp_path, broken):
    src = preset("gelsight_mini").calibration.folder
    folder = tmp_path / "calib"
    shutil.copytree(src, folder)
    if broken in ("params.json", "polycalib.npz", "dataPack.npz"):
        (folder / broken).unlink()
        name = broken
    elif broken == "bad_json":
        (folder / "params.json").write_text(json.dumps({"sensor": {"pixmm": 0.03}}))
        name = "params.json"
    else:
        np.savez(folder / "polycalib.npz", grad_r=np.zeros((3, 3, 6)), grad_g=np.zeros((3, 3, 6)), grad_b=np.zeros((3, 3, 6)))
        name = "polycalib.npz"
    with pytest.raises(ConfigError, match=name.replace(".", r"\.")):
        load_calibration(folder)


def test_wrong_shapes_and_unknown_presets_are_named():
    with pytest.raises(ConfigError, match="not a preset name"):
        preset("digit_v9")
    s = preset("gelsight").at_resolution(320, 240)
    with pytest.raises(ConfigError, match="depth has shape"):
        render_rgb(torch.zeros(1, 480, 640), s)
    with pytest.raises(ConfigError, match="markers has shape"):
        render_rgb(torch.zeros(1, 240, 320), s, markers=torch.zeros(1, 5, 3))
