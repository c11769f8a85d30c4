"""Plumbing shared by the benchmarks: argument parsers, progress bars, the MPM warm-up, report
files, and the scripted-expert episode with its per-step timing split."""
from __future__ import annotations

import argparse
import json
import os

from .. import environment


# ---------------------------------------------------------------------------- command line
def cli(name: str, doc: str) -> argparse.ArgumentParser:
    """The argument parser of ``python -m gausstac_maniskill.bench <name>``; its help is ``doc``
    (the module docstring)."""
    return argparse.ArgumentParser(prog=f"python -m gausstac_maniskill.bench {name}", description=doc,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)


def arch_option(ap: argparse.ArgumentParser) -> None:
    """``--arch cpu|cuda|auto`` (default ``$GAUSSTAC_ARCH``, else auto)."""
    ap.add_argument("--arch", default=environment.read("GAUSSTAC_ARCH"), choices=["cpu", "cuda", "auto"])


# ---------------------------------------------------------------------------- output
def write_report(out_dir: str, filename: str, text: str) -> str:
    """Write ``text`` (the printed table) to ``out_dir/filename``; returns the path."""
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, filename)
    with open(path, "w") as f:
        f.write(text + "\n")
    return path


def write_json(out_dir: str, filename: str, obj, indent: int | None = None) -> str:
    """Write ``obj`` as JSON (``json.dump`` with ``indent``) to ``out_dir/filename``; returns the path."""
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, filename)
    with open(path, "w") as f:
        json.dump(obj, f, indent=indent)
    return path


def progress_bar(total, desc, enabled):
    """A tqdm bar of ``total`` steps (``enabled`` False: hidden; tqdm missing: a no-op bar)."""
    try:
        from tqdm import tqdm

        return tqdm(total=total, desc=desc, disable=not enabled, leave=False)
    except ImportError:  # pragma: no cover
        class _Null:
            def update(self, n): ...
            def close(self): ...
        return _Null()


# ---------------------------------------------------------------------------- solver warm-up
def warmup(contact: str = "particle") -> None:
    """Compile the MPM solver's kernels on a tiny world (``contact``: MPMWorld's contact mode)
    so that timings exclude Taichi's JIT."""
    import numpy as np

    from ..config import Material, SolverSettings
    from ..geometry import Sphere, box_particles
    from ..mpm import MPMWorld
    from ..transforms import make_pose

    world = MPMWorld(SolverSettings(dx=2e-3, gravity=(0, 0, 0), mass_scaling=1.0, max_substeps=2000), contact=contact)
    world.add_link("ground", np.eye(4))
    pts = box_particles([0, 0, -4e-3], [4e-3, 4e-3, 0], 1e-3)
    world.add_group("pad", pts, Material(E=3.0e5, nu=0.45, density=1100.0), link="ground", kinematic=pts[:, 2] < -3e-3)
    world.add_slip_wall(0, 0.0)
    world.add_collider(Sphere(radius=2e-3, pose=make_pose([0, 0, 1.9e-3])))
    world.step(1e-5)


# ---------------------------------------------------------------------------- env episodes
#: the parts of an env step that ``GaussTacEnv.step_timing`` times, and their sum
STEP_PARTS = ("physics", "mpm", "tactile", "render", "total")


def step_split_ms(timing: list[dict]) -> dict[str, float]:
    """Mean wall time [ms] per step of each of :data:`STEP_PARTS` over ``timing`` (one
    ``{**env.step_timing, "total": seconds}`` dict per step; a missing part counts 0)."""
    return {key: 1e3 * sum(t.get(key, 0.0) for t in timing) / max(len(timing), 1) for key in STEP_PARTS}


def split_cells(split: dict[str, float]) -> str:
    """``"physics | mpm | tactile | render | total"`` table cells [ms] of :func:`step_split_ms`."""
    return " | ".join(f"{split[key]:.0f}" for key in STEP_PARTS)


def run_expert_episode(env, seed: int, desc: str, each_step=None, settle: int = 0, replay=None):
    """Reset ``env`` with ``seed`` and step it with its scripted expert until success (and
    ``settle`` more steps) or the task's time limit, timing every step.

    Args:
        each_step: called as ``each_step(info, action)`` after every step (per-step records).
        settle: control steps the expert goes on after the first success.
        replay: a list of actions to play instead of the expert's (open loop, every one of
            them, whatever the success).

    Returns:
        ``(obs, info, done, timing, expert)``: the last observation and info, the control
        step at which the task first succeeded (None: never), one ``{**env.step_timing,
        "total": s}`` per step (for :func:`step_split_ms`), and the expert.
    """
    import time

    from mani_skill.utils.registration import REGISTERED_ENVS
    from tqdm import tqdm

    from ..experts import make_expert

    u = env.unwrapped
    obs, info = env.reset(seed=seed)
    expert = make_expert(env)
    expert.reset()
    timing, done = [], None
    steps = len(replay) if replay is not None else REGISTERED_ENVS[u.spec.id].max_episode_steps
    for k in tqdm(range(steps), desc=desc, leave=False):
        t0 = time.perf_counter()
        action = replay[k] if replay is not None else expert.act(obs)
        obs, _, _, _, info = env.step(action)
        timing.append({**u.step_timing, "total": time.perf_counter() - t0})
        if each_step is not None:
            each_step(info, action)
        if done is None and bool(info["success"][0]):
            done = k
        if replay is None and done is not None and k >= done + settle:
            break
    return obs, info, done, timing, expert
