"""GaussTac for ManiSkill: visuo-tactile simulation for dexterous robot hands.

Soft fingertip pads ride on rigid link poses (SAPIEN or MuJoCo). By default the pads
are solved at equilibrium each step (:mod:`gausstac_maniskill.fem`, linear cut-cell FEM,
``pad_solver="auto"``); Taichi MLS-MPM pads are an option (``pad_solver="mpm"``). Soft
objects are MLS-MPM particles, rigid objects SDF colliders; a Taichi 3D Gaussian Splatting
camera renders the scene. Units are SI throughout (m, kg, s, Pa).

``import gausstac_maniskill`` is light (no ManiSkill, torch or Taichi import): it
registers the tasks (``GaussTac-*-v1``) with gymnasium, so ``gym.make("GaussTac-...")``
works at once; the first such ``gym.make``, :func:`register`, or importing
:mod:`gausstac_maniskill.agents` / :mod:`gausstac_maniskill.tasks` registers the agents
(``allegro_hand_right_gausstac``, ...) and tasks with ManiSkill itself (at import already
when ManiSkill is imported first). Submodules load on first use
(``gausstac_maniskill.backend``, ``.tasks``, ...).
"""
from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: Submodules and subpackages, imported on first attribute access.
_SUBMODULES = ("add_tactile", "agents", "assets", "backend", "batch", "bench", "cache", "cli", "collect", "config", "cosim", "demo",
               "environment", "errors", "experts", "fem", "geometry", "mpm", "obs_wrappers", "pose", "reference",
               "optical", "render", "replay", "sensors", "splat", "stock_tasks", "tactile", "tasks", "transforms", "urdf")

__all__ = ["__version__", "register", "make_tactile", *_SUBMODULES]


def register() -> None:
    """Register the GaussTac agents and tasks with ManiSkill (``REGISTERED_AGENTS``,
    ``REGISTERED_ENVS``) now; imports ManiSkill. Idempotent."""
    from ._registry import register_with_maniskill

    register_with_maniskill()


def __getattr__(name: str):
    if name == "make_tactile":  # a stock ManiSkill task with pads: stock_tasks.make_tactile
        return importlib.import_module(f"{__name__}.stock_tasks").make_tactile
    if name in _SUBMODULES:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_SUBMODULES))


def _install() -> None:
    from ._registry import install

    install()


_install()
