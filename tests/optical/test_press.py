"""A ball pressed into a sensor's flat gel and imaged (gausstac_maniskill.optical.press), on
coarse layers. Against theory: the contact radius of a shallow press is Hertz's. The rest guards
conventions (where the touch appears, which way the markers flow) and the arguments' errors."""
import numpy as np
import pytest

from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.optical import image, preset, press_gel, press_sphere, slide_gel

COARSE = dict(element=0.25e-3, half_width=4e-3)


def test_shallow_press_has_hertz_contact_radius():
    """R = 10 mm pressed 0.1 mm into the 4 mm GelSight layer: a = √(Rδ) = 1 mm (a/h = 0.25, where
    the bonded layer moves the radius by a few per cent; the force it raises by ~40 %)."""
    s = preset("gelsight")
    gel = press_gel(s, 10e-3, 0.1e-3, **COARSE)
    a = image(gel, s, markers=False).contact_radius_px * s.camera.mm_per_px * 1e-3
    assert a == pytest.approx(np.sqrt(10e-3 * 0.1e-3), rel=0.08)
    hertz = 4 / 3 * s.gel.E / (1 - s.gel.nu ** 2) * np.sqrt(10e-3) * 0.1e-3 ** 1.5
    assert hertz < gel.force[2] < 2 * hertz


def test_press_sphere_images_the_touch_where_asked():
    s = preset("gelsight")
    press = press_sphere(s, None, 0.6e-3, center_px=(200.0, 300.0), **COARSE)
    rgb, markers, radius = press  # unpacks as (rgb, markers, contact_radius_px)
    assert rgb.shape == (480, 640, 3) and rgb.dtype == np.uint8 and markers.shape == press.marker_rest.shape
    w = np.clip(press.depth, 0, None)
    rows, cols = np.mgrid[:480, :640]
    assert (w * cols).sum() / w.sum() == pytest.approx(200, abs=0.5)  # the surface's dent sits on its centre
    assert (w * rows).sum() / w.sum() == pytest.approx(300, abs=0.5)
    bg = np.array(s.calibration.background)
    plain = image(press.gel, s, (200.0, 300.0), markers=False).rgb
    assert np.array_equal(plain[:100, 400:], bg[:100, 400:])  # far from it: the no-contact frame
    assert (rgb < plain).any()  # the markers, dark dots
    assert 20 < radius < 0.6e-3 ** 0.5 * 2e-3 ** 0.5 * 1.6 / (s.camera.mm_per_px * 1e-3)
    deeper = press_gel(s, None, 1.0e-3, **COARSE)
    assert image(deeper, s).contact_radius_px > radius and deeper.force[2] > press.gel.force[2] > 0


def test_markers_flow_with_a_slide():
    """A ball dragged along +x with friction pulls the markers under it along +x; without
    friction they move far less along the drag."""
    s = preset("gelsight")
    stuck = image(slide_gel(s, None, 0.6e-3, 1.0e-3, steps=4, friction=1.0, half_width=5e-3)[-1], s)
    free = image(slide_gel(s, None, 0.6e-3, 1.0e-3, steps=4, friction=0.0, half_width=5e-3)[-1], s)
    near = np.hypot(*(stuck.marker_rest - [319.5 + 1.0 / 0.0295 / 2, 239.5]).T) < 40
    pull = (stuck.markers - stuck.marker_rest)[near, 0].mean()
    assert pull > 5 and pull > 3 * abs((free.markers - free.marker_rest)[near, 0].mean())


@pytest.mark.parametrize("kwargs, word", [(dict(radius=None, depth=2.5e-3), "depth"),
                                          (dict(radius=-1.0, depth=1e-3), "radius"),
                                          (dict(radius=None, depth=1e-3, element=3e-3), "element")])
def test_bad_press_names_the_argument(kwargs, word):
    with pytest.raises(ConfigError, match=word):
        press_gel("gelsight", **kwargs)
