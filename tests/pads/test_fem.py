"""The equilibrium pads (pads/fem.py): one EquilibriumPad per pad, at rest away from objects,
their state named per pad; finite-strain pads hand over to the MPM pads before any touch."""
import warnings

import numpy as np
import pytest

from gausstac_maniskill.errors import ConfigError

DX = 2e-3


def _scene(**kwargs):
    from gausstac_maniskill.bench import scenes as bp
    from gausstac_maniskill.config import SolverSettings
    from gausstac_maniskill.cosim import GaussTacSim

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = GaussTacSim([bp.index_spec()], {bp.INDEX: bp.LINK_POSE}, settings=SolverSettings(dx=DX), **kwargs)
    return sim, bp


def test_an_equilibrium_pad_at_rest_builds_nothing_and_reads_zeros():
    from gausstac_maniskill.fem.sensor import EquilibriumPad

    sim, bp = _scene(pad_solver="fem")
    fem = sim.solvers["fem"]
    assert isinstance(fem.pads[bp.INDEX], EquilibriumPad) and fem.pads[bp.INDEX].model == "linear"
    assert not fem.awake[bp.INDEX] and not fem.touched
    maps = fem.tactile()[bp.INDEX]
    assert all(not v.any() for v in maps.values())
    assert np.array_equal(fem.contact_forces(bp.INDEX), np.zeros((sim.pads[bp.INDEX].num_particles, 3)))
    x, F = fem.particles(bp.INDEX)
    rest = sim.pads[bp.INDEX].rest @ bp.LINK_POSE[:3, :3].T + bp.LINK_POSE[:3, 3]
    assert np.abs(x - rest).max() < 1e-6 and np.allclose(F, bp.LINK_POSE[:3, :3], atol=1e-6)
    flat = fem.flat_state()
    assert flat and all(k.startswith("fem0_") for k in flat) and not flat["fem0_solved"][0]
    assert fem.pads[bp.INDEX]._body is None  # nothing assembled at rest
    assert fem.link_contacts(bp.INDEX) == {}
    f, tau = fem.link_wrench(bp.INDEX, np.zeros(3), np.zeros(3))
    assert not f.any() and not tau.any()


def test_the_flat_state_of_an_equilibrium_pad_is_required_to_load():
    sim, bp = _scene(pad_solver="fem")
    state = {k: v for k, v in sim.flat_state().items() if not k.startswith("fem0_")}
    with pytest.raises(ConfigError, match="fem0_.*pad_solver='mpm'"):
        sim.load_flat_state(state)


def test_finite_strain_pads_become_mpm_pads_when_a_soft_object_comes_first():
    from gausstac_maniskill.config import PadSolverSettings

    sim, bp = _scene(pad_settings=PadSolverSettings(fem_model="neo_hookean"))
    assert sim.pad_solver == "fem" and sim.solvers["fem"].names == [bp.INDEX]
    sim.add_soft_object("block", np.zeros((8, 3)) + [0.0, 0.0, 0.2], bp.index_spec().material)
    assert sim.pad_solver == "mpm" and sim.solvers["mpm"].names == [bp.INDEX] and not len(sim.solvers["fem"])
    assert not sim.is_awake(bp.INDEX) and sim.tactile()[bp.INDEX]["force"].shape == (16, 16)
    with pytest.raises(ConfigError, match="fem_model='linear' only"):
        sim2, _ = _scene(pad_solver="fem", fem_model="neo_hookean")
        sim2.add_soft_object("block", np.zeros((8, 3)) + [0.0, 0.0, 0.2], bp.index_spec().material)


def test_equilibrium_pads_are_no_groups_of_the_world_and_lead_the_particle_rows():
    sim, bp = _scene(pad_solver="fem")
    n = sim.pads[bp.INDEX].num_particles
    assert not sim.world.groups  # nothing of the pad in the MPM world
    assert sim.solved_rows == n and sim.particle_rows(bp.INDEX) == (0, n)
    x, F = sim.particles()
    assert x.shape == (n, 3) and F.shape == (n, 3, 3) and x.dtype == np.float32
    np.testing.assert_array_equal(x, sim.pad_particles(bp.INDEX)[0])
    np.testing.assert_array_equal(sim.rest_positions(), x)
    assert np.array_equal(sim.carry_rows(np.arange(n)), np.ones(n, np.int32))
    where, frames = sim.equilibrium_frames(np.arange(0, n, 7))
    np.testing.assert_array_equal(frames[:, :, 3], x[where * 7])
    assert sim.flat_state()["group_awake"].shape == (0,)


def test_finite_strain_pads_join_the_world_asleep_when_they_become_mpm_pads():
    from gausstac_maniskill.config import PadSolverSettings

    sim, bp = _scene(pad_settings=PadSolverSettings(fem_model="neo_hookean"))
    assert not sim.world.groups
    sim.add_soft_object("block", np.zeros((8, 3)) + [0.0, 0.0, 0.2], bp.index_spec().material)
    g = sim.world.group(sim.world_name(bp.INDEX))
    assert [h.name for h in sim.world.groups] == [bp.INDEX, "block"] and not g.awake
    assert sim.particle_rows(bp.INDEX) == (g.start, g.stop) and sim.solved_rows == 0
    rest = sim.pads[bp.INDEX].rest @ bp.LINK_POSE[:3, :3].T + bp.LINK_POSE[:3, 3]
    assert np.abs(sim.pad_particles(bp.INDEX)[0] - rest).max() < 1e-6
