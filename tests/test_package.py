"""The package itself: a light ``import gausstac_maniskill``, its gymnasium entries, the assets."""
import subprocess
import sys

import gymnasium as gym

import gausstac_maniskill
from gausstac_maniskill import _registry
from gausstac_maniskill.assets import ASSET_ROOT, asset_path


def test_import_is_light_and_registers_the_tasks_with_gymnasium():
    code = ("import sys, gymnasium as gym, gausstac_maniskill\n"
            "heavy = [m for m in ('mani_skill', 'torch', 'taichi', 'sapien', 'trimesh', 'mujoco') if m in sys.modules]\n"
            "print(heavy, all(t in gym.registry for t in gausstac_maniskill._registry.TASKS))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["[]", "True"]


def test_light_entries_match_maniskills_registration():
    gausstac_maniskill.register()
    from mani_skill.utils.registration import REGISTERED_ENVS

    assert sorted(e for e in REGISTERED_ENVS if e.startswith("GaussTac-")) == sorted(_registry.TASKS)
    for uid, steps in _registry.TASKS.items():
        real = gym.registry.pop(uid)
        try:
            _registry.register_light()  # makes the missing entry: this one
            light = gym.registry[uid]
        finally:
            gym.registry[uid] = real
        assert _registry.is_light(light) and not _registry.is_light(real), uid
        assert REGISTERED_ENVS[uid].max_episode_steps == steps
        for field in ("max_episode_steps", "disable_env_checker", "order_enforce", "kwargs", "additional_wrappers"):
            assert getattr(light, field) == getattr(real, field), (uid, field)


def test_lazy_submodules():
    assert "backend" in dir(gausstac_maniskill)
    assert gausstac_maniskill.errors.ConfigError.__name__ == "ConfigError"
    try:
        gausstac_maniskill.no_such_module
    except AttributeError as e:
        assert "no_such_module" in str(e)
    else:
        raise AssertionError("no AttributeError")


def test_assets_are_found_through_the_package():
    assert (ASSET_ROOT / "allegro_hand_right" / "gaussians.ply").is_file()
    assert (ASSET_ROOT / "allegro_hand_right" / "links.json").is_file()
    assert asset_path("ability_hand_right", "finger_L2_hull.obj").is_file()
    from gausstac_maniskill.agents import AllegroHandRightGaussTac
    from gausstac_maniskill.agents.ability import ABILITY_FINGER_HULL
    from gausstac_maniskill.demo import ASSET_DIR

    assert AllegroHandRightGaussTac.gausstac_gaussians == str(ASSET_DIR) == str(asset_path("allegro_hand_right"))
    assert ABILITY_FINGER_HULL == str(asset_path("ability_hand_right", "finger_L2_hull.obj"))
