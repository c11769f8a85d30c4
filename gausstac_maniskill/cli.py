"""Command line: ``gausstac demo | bench <name> | build-asset | collect | replay``.

* ``gausstac demo`` — the main demo (see README); writes PNG/MP4 files under ``out/``.
* ``gausstac bench <name> [options]`` — benchmarks (``hertz``, ``pad``, ``splat``, ...) that
  print what they measured.
* ``gausstac build-asset [options]`` — hand Gaussians (``gaussians.ply`` + ``links.json``)
  from a URDF's visual meshes, or aligned from a scan.
* ``gausstac collect <env_id> [options]`` — record scripted-expert demonstrations (h5 + json),
  same as ``python -m gausstac_maniskill.collect``.
* ``gausstac replay --traj-path T.h5 [options]`` — ManiSkill's trajectory replay with the GaussTac
  tasks registered, same as ``python -m gausstac_maniskill.replay``.
"""
from __future__ import annotations

import argparse
import sys


def _demo(argv: list[str]) -> int:
    from . import demo

    return demo.main(argv)


def _bench(argv: list[str]) -> int:
    from .bench.__main__ import main as bench_main

    return bench_main(argv)


def _build_asset(argv: list[str]) -> int:
    from .splat import build

    return build.main(argv)


def _collect(argv: list[str]) -> int:
    from . import collect

    return collect.main(argv)


def _replay(argv: list[str]) -> int:
    import multiprocessing as mp

    from . import replay

    mp.set_start_method("spawn", force=True)  # as ManiSkill's script: -n N workers must not fork Taichi/SAPIEN
    return replay.main(argv)


COMMANDS = {"demo": _demo, "bench": _bench, "build-asset": _build_asset, "collect": _collect, "replay": _replay}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(prog="gausstac", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", choices=sorted(COMMANDS))
    if not argv or argv[0] in ("-h", "--help"):
        parser.print_help()
        return 0 if argv else 2
    args, rest = parser.parse_known_args(argv[:1])
    try:
        return int(COMMANDS[args.command](argv[1:]) or 0)
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # noqa: BLE001 - our own errors print as one clear line
        from .errors import GaussTacError

        if isinstance(exc, GaussTacError):
            print(f"gausstac {args.command}: error: {exc}", file=sys.stderr)
            return 1
        raise


if __name__ == "__main__":
    sys.exit(main())
