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
    inner = np.all(np.abs(s[:, :2]) < half - index_pad.footprint, axis=1)
    np.testing.assert_allclose(b.weight[inner].sum(1), 1.0, atol=1e-12)
    outside = np.any(np.abs(s[:, :2]) > half + index_pad.footprint, axis=1)
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


def _maps(pad, binning, magnitude=None, push=None):
    """Maps of surface particles pushed along -z by ``magnitude`` [N] each, or displaced by
    ``push`` [m] into the pad (link = world)."""
    forces, positions = np.zeros((pad.num_particles, 3)), pad.rest.copy()
    z = pad.sensor_frame[:3, 2]
    if magnitude is not None:
        forces[pad.surface] = -magnitude[pad.surface, None] * z
    if push is not None:
        positions[pad.surface] -= push[pad.surface, None] * z
    m = tactile_maps(pad, binning, positions, np.eye(4), forces)
    return {k: v.numpy().astype(np.float64) for k, v in m.items()}


def test_maps_filter_a_pattern_of_the_grid_cell_and_keep_a_smooth_load(index_pad):
    """Each particle stands for one grid cell in the maps (Pad.footprint). Guards the filter,
    not the physics (bench pad's map L2 between resolutions is the evidence): a ±50 %
    alternation from one particle column to the next (period dx = 1 mm, the pattern a grid
    imprints on the particles' share of contact and motion) reads flat in the force and the
    depth map, where the particle's own square beats to 1.22 between neighbouring taxels; a
    smooth dome 4 mm in radius keeps its total and its shape within 3 % (L2)."""
    pad = index_pad
    assert pad.cell == 1e-3 and pad.footprint == 1e-3
    cell, own = TaxelBinning.for_pad(pad), TaxelBinning.for_pad(pad, pad.spacing)
    column = np.floor(pad.rest[:, 1] / pad.spacing + 1e-6).astype(int)  # link y: the sensor's -y
    alternating = 1.0 + 0.5 * np.where(column % 2 == 0, 1.0, -1.0)
    middle = lambda m: m[6:10, 6:10]  # noqa: E731 - the flat middle of the pad
    for key, load in (("force", dict(magnitude=1e-3 * alternating)), ("depth", dict(push=1e-4 * alternating))):
        m_own, m_cell = middle(_maps(pad, own, **load)[key]), middle(_maps(pad, cell, **load)[key])
        assert m_own.max() / m_own.min() > 1.15, key
        assert m_cell.max() / m_cell.min() < 1.01, key
    s = pad.sensor_coords()
    dome = 1e-3 * np.clip(1.0 - (s[:, 0] ** 2 + s[:, 1] ** 2) / 4e-3 ** 2, 0.0, None)
    m_own, m_cell = _maps(pad, own, magnitude=dome)["force"], _maps(pad, cell, magnitude=dome)["force"]
    assert m_cell.sum() == pytest.approx(m_own.sum(), rel=1e-6)  # (float32 maps)
    assert np.linalg.norm(m_cell - m_own) / np.linalg.norm(m_own) < 0.03
    with pytest.raises(ValueError, match="footprint"):
        TaxelBinning.for_pad(pad, 0.0)
