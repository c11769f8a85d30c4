"""Benchmarks: ``python -m gausstac_maniskill.bench <name>`` (see ``__main__``); each prints the
table it measured and writes it under ``out/``."""
from __future__ import annotations

import argparse
import os


def cli(name: str, doc: str) -> argparse.ArgumentParser:
    """The argument parser of ``python -m gausstac_maniskill.bench <name>``; its help is ``doc``
    (the module docstring)."""
    return argparse.ArgumentParser(prog=f"python -m gausstac_maniskill.bench {name}", description=doc,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)


def arch_option(ap: argparse.ArgumentParser) -> None:
    """``--arch cpu|cuda|auto`` (default ``$GAUSSTAC_ARCH``, else auto)."""
    ap.add_argument("--arch", default=os.environ.get("GAUSSTAC_ARCH", "auto"), choices=["cpu", "cuda", "auto"])


def write_report(out_dir: str, filename: str, text: str) -> str:
    """Write ``text`` (the printed table) to ``out_dir/filename``; returns the path."""
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, filename)
    with open(path, "w") as f:
        f.write(text + "\n")
    return path


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
