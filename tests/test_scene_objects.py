"""What tasks register: the captured scene's argument checks, and a captured object's checks on
its actor (no env is built)."""
import sys
from types import SimpleNamespace

import pytest

from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.scene_objects import SoftObject, captured_object, load_scene_capture


def test_no_scene_and_the_scene_arguments_that_do_not_fit():
    assert load_scene_capture(None, None, "splat") is None
    with pytest.raises(ConfigError, match="scene_pose was given without scene_ply"):
        load_scene_capture(None, {"scale": 1.0}, "splat")
    with pytest.raises(ConfigError, match="scene_ply needs camera='splat'.*camera='sapien'"):
        load_scene_capture("scene.ply", None, "sapien")


def test_captured_object_needs_an_actor_with_a_collision_shape():
    from gausstac_maniskill.splat.example_scene import EXAMPLE_SCENE

    actor = SimpleNamespace(name="mug", get_first_collision_mesh=lambda to_world_frame: None)
    with pytest.raises(ConfigError, match=r"add_captured_object\('mug'\): actor 'mug' has no collision shape"):
        captured_object("mug", actor, EXAMPLE_SCENE)


def test_soft_object_holds_its_particle_source():
    soft = SoftObject("sponge", lambda b: (None, None, None), material=None)
    assert soft.name == "sponge" and soft.particles(0) == (None, None, None)


def test_a_mis_scaled_capture_warns_at_the_callers_caller():
    import numpy as np

    from gausstac_maniskill.errors import AssetWarning
    from gausstac_maniskill.splat.example_scene import EXAMPLE_SCENE

    mesh = SimpleNamespace(extents=np.array([0.001, 0.001, 0.001]))
    actor = SimpleNamespace(name="bead", get_first_collision_mesh=lambda to_world_frame: mesh)

    def add_captured_object():  # stands for GaussTacEnv.add_captured_object
        return captured_object("bead", actor, EXAMPLE_SCENE)

    with pytest.warns(AssetWarning, match=r"captured object 'bead'\).*collision mesh spans 0.001 m") as rec:
        line, obj = sys._getframe().f_lineno, add_captured_object()  # the task's line the warning names
    assert (rec[0].filename, rec[0].lineno) == (__file__, line) and obj.name == "bead" and obj.actor is actor
