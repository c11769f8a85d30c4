"""``python -m gausstac_maniskill.bench <name> [options]`` — run a benchmark.

Each benchmark module exposes ``main(argv: list[str]) -> int`` and prints the
table it measured.
"""
from __future__ import annotations

import importlib
import sys

BENCHMARKS = {
    "hertz": "gausstac_maniskill.bench.hertz",
    "splat": "gausstac_maniskill.bench.splat",
    "hand": "gausstac_maniskill.bench.hand",
    "envs": "gausstac_maniskill.bench.envs",
    "thinlayer": "gausstac_maniskill.bench.thinlayer",
    "pad": "gausstac_maniskill.bench.pad",
    "kernels": "gausstac_maniskill.bench.kernels",
    "compile": "gausstac_maniskill.bench.compile",
    "soft": "gausstac_maniskill.bench.soft",
    "patch": "gausstac_maniskill.bench.patch",
    "look": "gausstac_maniskill.bench.look",
    "close": "gausstac_maniskill.bench.close",
    "drive_contact": "gausstac_maniskill.bench.drive_contact",
    "grasp": "gausstac_maniskill.bench.grasp",
    "sponge": "gausstac_maniskill.bench.sponge",
    "resolution": "gausstac_maniskill.bench.resolution",
    "hold": "gausstac_maniskill.bench.hold",
    "batch": "gausstac_maniskill.bench.batch",
    "scale": "gausstac_maniskill.bench.scale",
    "optical": "gausstac_maniskill.bench.optical",
    "motion": "gausstac_maniskill.bench.motion",
    "quasistatic": "gausstac_maniskill.bench.quasistatic",
    "touch": "gausstac_maniskill.bench.touch",
}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help") or argv[0] not in BENCHMARKS:
        print("usage: python -m gausstac_maniskill.bench {%s} [options]" % "|".join(BENCHMARKS))
        return 0 if (argv and argv[0] in ("-h", "--help")) else 2
    module = importlib.import_module(BENCHMARKS[argv[0]])
    return int(module.main(argv[1:]) or 0)


if __name__ == "__main__":
    sys.exit(main())
