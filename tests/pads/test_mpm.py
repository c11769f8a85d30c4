"""The MPM pads (pads/mpm.py): groups of the scene's world, asleep at rest, woken by an object."""
import warnings

import numpy as np

DX = 2e-3


def _scene():
    from gausstac_maniskill.bench import scenes as bp
    from gausstac_maniskill.config import SolverSettings
    from gausstac_maniskill.cosim import GaussTacSim

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = GaussTacSim([bp.index_spec()], {bp.INDEX: bp.LINK_POSE}, settings=SolverSettings(dx=DX),
                          pad_solver="mpm")
    return sim, bp


def test_an_mpm_pad_is_a_world_group_that_sleeps_at_rest_and_wakes_near_an_object():
    sim, bp = _scene()
    mpm = sim.solvers["mpm"]
    g = sim.world.group(sim.world_name(bp.INDEX))
    assert g.stop - g.start == sim.pads[bp.INDEX].num_particles
    assert not mpm.awake[bp.INDEX] and not g.awake  # nothing near: asleep, in the world too
    assert mpm.slots() == [(bp.INDEX, bp.INDEX)]
    W = bp.LINK_POSE @ sim.pads[bp.INDEX].sensor_frame
    sim.add_rigid_object("ball", bp.indenter_collider("sphere", bp.indenter_pose("sphere", W, 1e-3), 0.5))
    assert mpm.awake[bp.INDEX] and sim.world.group(bp.INDEX).awake
    maps = sim.step({bp.INDEX: bp.LINK_POSE}, 0.01)[bp.INDEX]
    assert maps["depth"].shape == (16, 16)
    x, F = sim.pad_particles(bp.INDEX)
    assert x.dtype == np.float32 and F.shape == (len(x), 3, 3)
    assert mpm.state() == {} and mpm.flat_state() == {}  # the world holds the MPM pads' state


def test_a_sleeping_mpm_pad_is_carried_by_its_link():
    from gausstac_maniskill.transforms import make_pose

    sim, bp = _scene()
    mpm = sim.solvers["mpm"]
    assert mpm.carry(bp.INDEX) is None or np.allclose(mpm.carry(bp.INDEX), np.eye(4))
    moved = make_pose([0.01, 0.0, 0.0]) @ bp.LINK_POSE
    sim.step({bp.INDEX: moved}, 0.01)
    D = mpm.carry(bp.INDEX)
    assert D is not None and np.allclose(D @ bp.LINK_POSE, moved)
    x, _ = sim.pad_particles(bp.INDEX)
    rest = sim.pads[bp.INDEX].rest @ moved[:3, :3].T + moved[:3, 3]
    assert np.abs(x - rest).max() < 1e-6
