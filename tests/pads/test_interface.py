"""The pad-solver interface (pads/interface.py) and the settings every pad solver takes."""
import inspect
import warnings

import numpy as np
import pytest

from gausstac_maniskill.config import PadSolverSettings
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.pads import EquilibriumPads, MPMPads, PadSolver

DX = 2e-3  # the coarsest lattice, for speed


def _scene(**kwargs):
    from gausstac_maniskill.bench import scenes as bp
    from gausstac_maniskill.config import SolverSettings
    from gausstac_maniskill.cosim import GaussTacSim

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the 2 mm grid's ResolutionWarning
        return GaussTacSim([bp.index_spec()], {bp.INDEX: bp.LINK_POSE}, settings=SolverSettings(dx=DX), **kwargs)


def test_the_interface_is_abstract_and_both_solvers_implement_it():
    with pytest.raises(TypeError):
        PadSolver(None, PadSolverSettings())  # noqa: abstract
    for cls, kind in ((EquilibriumPads, "fem"), (MPMPads, "mpm")):
        assert issubclass(cls, PadSolver) and cls.kind == kind
        assert not inspect.isabstract(cls)


@pytest.mark.parametrize("solver", ["fem", "mpm"])
def test_the_scene_holds_one_solver_per_kind_and_each_pad_in_one(solver):
    from gausstac_maniskill.bench import scenes as bp

    sim = _scene(pad_solver=solver)
    assert set(sim.solvers) == {"fem", "mpm"}
    assert sim.pad_solver_of(bp.INDEX) is sim.solvers[solver]
    assert sim.solvers[solver].names == [bp.INDEX] and not len(sim.solvers[{"fem": "mpm", "mpm": "fem"}[solver]])
    assert not sim.is_awake(bp.INDEX)  # nothing near: asleep
    maps = sim.tactile()[bp.INDEX]
    assert set(maps) == {"depth", "shear", "force", "pressure"} and all(not v.any() for v in maps.values())
    assert np.array_equal(sim.pad_stress_force(bp.INDEX), np.zeros(3))


def test_settings_are_validated_and_travel_as_one_object():
    assert PadSolverSettings().initial_solver == "fem"
    assert PadSolverSettings(surface="particles").initial_solver == "mpm"
    for bad, match in ((dict(solver="implicit"), "pad_solver='implicit'"), (dict(surface="skin"), "pad_surface='skin'"),
                       (dict(solver="fem", surface="particles"), "pad_surface='mesh'"),
                       (dict(fem_model="hooke"), "fem_model 'linear' or 'neo_hookean'"),
                       (dict(fem_precompute="yes"), "fem_precompute"), (dict(sleep_margin=-1.0), "sleep_margin")):
        with pytest.raises(ConfigError, match=match):
            PadSolverSettings(**bad)
    settings = PadSolverSettings(solver="mpm", sleep_margin=1e-2)
    sim = _scene(pad_settings=settings)
    assert sim.pad_settings is settings and sim.sleep_margin == 1e-2
    assert all(s.settings is settings for s in sim.solvers.values())
    assert _scene(pad_solver="mpm", sleep_margin=1e-2).pad_settings == settings  # the shorthand
    with pytest.raises(ConfigError, match="not both"):
        _scene(pad_settings=settings, pad_solver="mpm")
