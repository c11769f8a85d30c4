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
