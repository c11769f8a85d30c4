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
