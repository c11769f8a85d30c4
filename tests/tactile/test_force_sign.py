"""No taxel of a force map reads a pull (tactile/extract.py: compressive_force)."""
import numpy as np
import pytest
import torch

from gausstac_maniskill.tactile import TaxelBinning, allegro_pad_specs, build_pad, tactile_maps
from gausstac_maniskill.tactile.extract import compressive_force
from gausstac_maniskill.urdf import default_hand_urdf, link_mesh


def _random_maps(seed, n=200):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        H, W = (int(v) for v in rng.integers(1, 17, 2))
        f = rng.random((H, W)) * (rng.random((H, W)) < 0.5)  # a contact footprint, zeros elsewhere
        f[rng.random((H, W)) < 0.15] *= -3.0 * rng.random()  # some taxels pull
        yield f


def test_compressive_force_keeps_the_total_and_the_footprint():
    """Every taxel ≥ 0; the total kept where it is positive (else 0: nothing presses); taxels
    that read 0 stay 0, none reads more than it pressed; a map without a pull is returned as is."""
    for f in _random_maps(0):
        g = compressive_force(f.ravel(), *f.shape).reshape(f.shape)
        assert g.min() >= 0.0
        if f.sum() > 0:
            assert g.sum() == pytest.approx(f.sum(), rel=1e-12, abs=1e-15)
        else:
            assert not g.any()
        assert not g[f == 0].any()
        assert np.all(g <= np.maximum(f, 0.0) * (1 + 1e-12))
        ok = np.maximum(f, 0.0).ravel()
        assert compressive_force(ok, *f.shape) is ok  # bit-identical without a pull


def test_compressive_force_of_a_batch_equals_each_map_and_keeps_its_dtype():
    rng = np.random.default_rng(2)
    maps = [rng.random((5, 7)) - 0.2 for _ in range(4)] + [np.abs(rng.random((5, 7)))]
    batch = torch.tensor(np.stack(maps), dtype=torch.float32)
    out = compressive_force(batch)
    assert out.dtype == torch.float32 and out.shape == batch.shape and float(out.min()) >= 0.0
    for m, o in zip(batch.double().numpy(), out.double().numpy()):
        np.testing.assert_allclose(o, compressive_force(m.ravel(), 5, 7).reshape(5, 7), atol=1e-6)
    assert torch.equal(out[-1], batch[-1])  # the map without a pull is untouched


def test_a_pull_is_taken_from_the_nearest_pressed_taxels():
    """A pulling edge taxel next to a press takes its deficit from its neighbours only: taxels two
    or more away, and the far press, keep their force."""
    f = np.zeros((6, 6))
    f[1:5, 1:3] = 1.0  # the press next to the edge column
    f[1:5, 5] = 2.0  # another press, away from it
    f[2, 0] = -0.3  # the pull
    g = compressive_force(f.ravel(), 6, 6).reshape(6, 6)
    assert g.min() >= 0.0 and g.sum() == pytest.approx(f.sum(), rel=1e-12)
    assert g[2, 0] == 0.0
    np.testing.assert_array_equal(g[:, 2:], f[:, 2:])  # beyond distance 1: unchanged
    np.testing.assert_array_equal(g[[0, 4, 5]], f[[0, 4, 5]])
    np.testing.assert_allclose(g[1:4, 1], 0.9)  # three neighbours of 1 N give 0.1 N each


@pytest.fixture(scope="module")
def index_pad():
    spec = next(s for s in allegro_pad_specs() if s.link == "link_3.0_tip")
    return build_pad(spec, link_mesh(default_hand_urdf(), spec.link), 0.5e-3, 1e-3)


def test_a_wall_contact_at_the_edge_reads_no_pull(index_pad):
    """Map level, as in the Touch task: a flat press in the middle of the pad and, at its edge
    column, a slipping contact on a wall across the sensor axis (normal force λ along the wall's
    normal, −x, Coulomb friction μλ pulling along +z: a valid compressive contact). The raw −z
    component pulls in the edge taxels; the map reads ≥ 0 everywhere and keeps the total."""
    pad = index_pad
    S = pad.sensor_frame[:3, :3]  # identity link pose: link frame = world
    s = pad.sensor_coords()
    half_x = 0.5 * pad.spec.layout.size[0]
    pitch = pad.spec.layout.size[0] / pad.spec.layout.cols
    press = pad.surface & (np.abs(s[:, 0]) < half_x - 3 * pitch) & (np.abs(s[:, 1]) < 4e-3)
    wall = pad.surface & (s[:, 0] < -half_x + 0.5 * pitch) & (np.abs(s[:, 1]) < 4e-3)
    assert press.sum() > 50 and wall.sum() > 5
    lam, mu = 2e-3, 0.5
    forces = np.zeros((pad.num_particles, 3))
    forces[press] = -5e-3 * S[:, 2]
    forces[wall] = lam * S[:, 0] + mu * lam * S[:, 2]  # the wall pushes +x (normal), drags +z (friction)
    binning = TaxelBinning.for_pad(pad)
    inside = (binning.taxel >= 0).any(axis=1)
    raw = binning.accumulate(inside, -(forces @ S[:, 2]))
    assert raw.min() < -1e-3  # the case: edge taxels that pull
    m = tactile_maps(pad, binning, pad.rest, np.eye(4), forces)["force"].numpy().astype(np.float64)
    assert np.isfinite(m).all() and m.min() >= 0.0
    assert m.sum() == pytest.approx(raw.sum(), rel=1e-6)
    np.testing.assert_array_equal(m.ravel()[raw == 0], 0.0)
