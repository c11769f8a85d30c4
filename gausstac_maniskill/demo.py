"""``gausstac demo``: the project's main demonstration, on the embedded default assets.

Until the hand pipeline lands, the demo presses a rigid sphere into a soft pad
(the Hertz benchmark in quick mode) and writes ``out/demo/hertz.png`` (force-depth
curve and pressure profile against Hertz theory) and ``hertz.md`` (the table).
"""
from __future__ import annotations

import argparse
import os


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="gausstac demo", description=__doc__)
    ap.add_argument("--out", default="out/demo", help="output folder")
    ap.add_argument("--arch", default=os.environ.get("GAUSSTAC_ARCH", "auto"), choices=["cpu", "cuda", "auto"])
    args = ap.parse_args(argv)
    from .bench import hertz

    return hertz.main(["--quick", "--out", args.out, "--arch", args.arch])
