"""Resampling a pad's particles onto its taxel grid (tactile/extract.py)."""
import numpy as np
import pytest

from gausstac_maniskill.tactile import TaxelBinning, allegro_pad_specs, build_pad, tactile_maps
from gausstac_maniskill.urdf import default_hand_urdf, link_mesh


@pytest.fixture(scope="module")
def index_pad():
    """The product's index pad at the default dx = 1 mm: a 0.5 mm particle lattice under
    1.25 mm taxels, the case where whole-particle binning aliases (2 or 3 columns a taxel)."""
    spec = next(s for s in allegro_pad_specs() if s.link == "link_3.0_tip")
    return build_pad(spec, link_mesh(default_hand_urdf(), spec.link), 0.5e-3, 1e-3)


def test_each_particle_is_shared_by_overlap(index_pad):
    b = TaxelBinning.for_pad(index_pad)
    s = index_pad.sensor_coords()
    half = 0.5 * np.array(index_pad.spec.layout.size)
    inner = np.all(np.abs(s[:, :2]) < half - index_pad.spacing, axis=1)
    np.testing.assert_allclose(b.weight[inner].sum(1), 1.0, atol=1e-12)
    outside = np.any(np.abs(s[:, :2]) > half + index_pad.spacing, axis=1)
    assert not b.weight[outside].any()


def test_uniform_pressure_gives_a_smooth_force_map(index_pad):
    """Every surface particle pushed by the same normal force f: the force map of the flat
    middle of the pad is uniform and adds up to the force applied inside the layout. With
    each particle given whole to the taxel of its centre, neighbouring taxels read 4f, 6f
    and 9f (max/min 2.25); shared by overlap they read 6.25 f within the dome's curvature."""
    pad = index_pad
    f = 1e-3
    forces = np.zeros((pad.num_particles, 3))
    normal_world = pad.sensor_frame[:3, 2]  # identity link pose: link frame = world
    forces[pad.surface] = -f * normal_world
    maps = tactile_maps(pad, TaxelBinning.for_pad(pad), pad.rest, np.eye(4), forces)
    m = maps["force"].numpy().astype(np.float64)
    middle = m[6:10, 6:10]
    assert middle.max() / middle.min() < 1.12, middle
    assert middle.mean() == pytest.approx(f * (1.25 / 0.5) ** 2, rel=0.06)
    s = pad.sensor_coords()
    half = 0.5 * np.array(pad.spec.layout.size)
    inner = pad.surface & np.all(np.abs(s[:, :2]) < half - pad.spacing, axis=1)
    assert m.sum() >= f * inner.sum() - 1e-9
    assert m.sum() <= f * pad.surface.sum() + 1e-9
    assert not maps["depth"].numpy().any()  # at rest: no depth anywhere
