"""TactileReadout: the maps read on the device in one launch (tactile/readout.py).

Guards that the kernel computes what the float64 NumPy reference ``tactile_maps`` computes
from the same particles (it is the same formula, so this checks the kernel's indexing,
frames and sums, not the physics of the maps), that a read copies no particle state back
to the host, and that it sees state restored on the host.
"""
import numpy as np
import pytest

from gausstac_maniskill.config import SolverSettings
from gausstac_maniskill.cosim import GaussTacSim
from gausstac_maniskill.mpm import Sphere
from gausstac_maniskill.pose import MujocoPoseSource
from gausstac_maniskill.tactile import TaxelBinning, allegro_pad_specs, tactile_maps
from gausstac_maniskill.transforms import make_pose

INDEX = "link_3.0_tip"
R = 6e-3


@pytest.fixture(scope="module")
def pressed():
    """The Allegro hand, its index pad pressed 0.8 mm by a 6 mm ball with friction that then
    slides 0.3 mm along the finger (depth, shear, force and pressure all nonzero); the other
    pads asleep."""
    names = [s.link for s in allegro_pad_specs()]
    poses = dict(zip(names, MujocoPoseSource().link_poses(names)[0].double().numpy()))
    sim = GaussTacSim(allegro_pad_specs(), poses, settings=SolverSettings(dx=1.5e-3), pad_solver="mpm")
    W = poses[INDEX] @ sim.pads[INDEX].sensor_frame
    centre = lambda d, s: make_pose(W[:3, 3] + W[:3, 2] * (R - d) + W[:3, 0] * s)  # noqa: E731
    sim.add_rigid_object("ball", Sphere(radius=R, pose=centre(-0.5e-3, 0.0), friction=0.8))
    for k in range(5):
        sim.step(poses, 0.02, {"ball": centre(0.8e-3 * min(1.0, (k + 1) / 3), 0.3e-3 * max(0, k - 2) / 2)})
    return sim, poses


def _reference(sim, name):
    pad, w = sim.pads[name], sim.world
    g, link = dict(zip(sim.pads, sim.pad_slots()))[name]
    return tactile_maps(pad, TaxelBinning.for_pad(pad), w.positions(g), w.link_pose(link), w.contact_forces(g),
                        w.stresses(g))


def test_device_maps_equal_the_numpy_reference(pressed):
    sim, _ = pressed
    sim._maps = {}
    maps = sim.tactile()
    ref = _reference(sim, INDEX)
    for key in ("depth", "shear", "force", "pressure"):
        got, want = maps[INDEX][key].cpu().numpy(), ref[key].numpy()
        assert got.shape == want.shape
        scale = np.abs(want).max()
        assert scale > 0, key  # the press reaches every map
        # the kernel works in float32 from the link's float32 pose: a 0.1 m coordinate rounds
        # to 4 nm (shear is about 6 nm off, 2e-5 of its largest value)
        atol = 2e-8 if key in ("depth", "shear") else 1e-5 * scale
        np.testing.assert_allclose(got, want, rtol=0, atol=atol, err_msg=key)
    assert float(maps[INDEX]["force"].sum()) > 0.05
    asleep = [n for n in sim.pads if not sim.is_awake(n)]
    assert asleep and all(not maps[n][k].any() for n in asleep for k in maps[n])


def test_a_read_copies_no_particle_state(pressed):
    sim, poses = pressed
    sim.step(poses, 0.02, {"ball": sim.world.colliders[0].pose})
    stale = set(sim.world._stale)  # fields the device holds newer than the host
    sim.tactile()
    assert {"x", "impulse", "tau", "F"} <= stale and sim.world._stale == stale


def test_a_read_sees_state_restored_on_the_host(pressed):
    sim, poses = pressed
    before = sim.tactile()[INDEX]["depth"].clone()
    saved = sim.flat_state()
    sim.step(poses, 0.02, {"ball": make_pose(sim.world.colliders[0].pose[:3, 3] + 0.05)})  # the ball leaves
    assert not sim.tactile()[INDEX]["depth"].equal(before)
    sim.load_flat_state(saved)
    assert sim.tactile()[INDEX]["depth"].equal(before)
