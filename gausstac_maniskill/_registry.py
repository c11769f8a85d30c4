"""Registration of the GaussTac tasks and agents without importing ManiSkill up front.

Importing ManiSkill is slow (torch, SAPIEN, its scene builders), so
``import gausstac_maniskill`` does not. It registers a light gymnasium entry per task
(:data:`TASKS`) with the arguments ManiSkill's ``register_env`` uses; its entry point
registers the agents and tasks with ManiSkill (:func:`register_with_maniskill`, which
replaces these entries with ManiSkill's own) and makes the env through ManiSkill. So
``gym.make("GaussTac-...-v1")`` works right after ``import gausstac_maniskill``, with the
same wrappers (``MSTimeLimit``) and ``max_episode_steps``.

ManiSkill's own registries (``REGISTERED_ENVS``, ``REGISTERED_AGENTS``) get the GaussTac
entries when :mod:`gausstac_maniskill.agents` / :mod:`gausstac_maniskill.tasks` are
imported, i.e. on the first ``gym.make`` of a GaussTac task, on
:func:`gausstac_maniskill.register`, or at ``import gausstac_maniskill`` when ManiSkill is
already imported.
"""
from __future__ import annotations

import importlib
import sys
from functools import partial

#: Task id -> ``max_episode_steps``, as in the ``@register_env`` lines under ``tasks/``
#: (``tests/test_package.py`` checks that the two agree).
TASKS = {
    "GaussTac-Gesture-v1": 50,
    "GaussTac-Touch-v1": 100,
    "GaussTac-PressCube-v1": 40,
    "GaussTac-SlideCube-v1": 60,
    "GaussTac-SqueezeSponge-v1": 40,
    "GaussTac-GraspLiftCube-v1": 100,
    "GaussTac-GraspSqueezeSponge-v1": 80,
}


def register_with_maniskill() -> None:
    """Import the agents and tasks: their modules register them with ManiSkill."""
    importlib.import_module("gausstac_maniskill.agents")
    importlib.import_module("gausstac_maniskill.tasks")


def make(env_id: str, **kwargs):
    """Entry point of a light gymnasium entry: register for real, then make through ManiSkill."""
    register_with_maniskill()
    from mani_skill.utils.registration import make as maniskill_make

    return maniskill_make(env_id, **kwargs)


def make_vec(env_id: str, **kwargs):
    """Vector entry point of a light entry (ManiSkill's ``make_vec``)."""
    register_with_maniskill()
    from mani_skill.utils.registration import make_vec as maniskill_make_vec

    return maniskill_make_vec(env_id, **kwargs)


def is_light(spec) -> bool:
    """Whether a gymnasium ``EnvSpec`` is one of the light entries."""
    ep = getattr(spec, "entry_point", None)
    return isinstance(ep, partial) and ep.func is make


def register_light() -> None:
    """Register the light gymnasium entries of :data:`TASKS` (ids already registered are kept)."""
    try:
        import gymnasium as gym
        from gymnasium.envs.registration import WrapperSpec
    except ImportError:  # pragma: no cover - gymnasium comes with ManiSkill
        return
    for uid, steps in TASKS.items():
        if uid in gym.registry:
            continue
        # ManiSkill's register_env arguments, so that both entries make the same env
        gym.register(
            uid, entry_point=partial(make, env_id=uid), vector_entry_point=partial(make_vec, env_id=uid),
            max_episode_steps=steps, disable_env_checker=True, kwargs={},
            additional_wrappers=[WrapperSpec("MSTimeLimit", entry_point="mani_skill.utils.registration:TimeLimitWrapper",
                                             kwargs=dict(max_episode_steps=steps))])


def drop_light() -> None:
    """Remove the light entries: ``tasks/__init__`` calls it before ManiSkill's
    ``register_env`` replaces them (which would otherwise warn "Overriding environment")."""
    gym = sys.modules.get("gymnasium")
    if gym is None:
        return
    for uid in TASKS:
        if is_light(gym.registry.get(uid)):
            del gym.registry[uid]


def install() -> None:
    """What ``import gausstac_maniskill`` does: the light entries, and the ManiSkill
    registration at once if ManiSkill is already imported (it then costs little)."""
    register_light()
    if "mani_skill" in sys.modules:
        register_with_maniskill()
