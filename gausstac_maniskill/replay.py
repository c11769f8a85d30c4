"""ManiSkill's ``replay_trajectory`` with the GaussTac tasks registered.

``python -m gausstac_maniskill.replay --traj-path demos/.../trajectory.rgb.pd_joint_delta_pos.physx_cpu.h5 [args]``

The arguments are those of ``python -m mani_skill.trajectory.replay_trajectory``
(``--help`` lists them) plus ``--overwrite``; the launcher imports :mod:`gausstac_maniskill`
first so that ``gym.make("GaussTac-...")`` works, also in the worker processes of ``-n N`` (they
are spawned and re-import this module). Useful forms::

    # re-render the recorded episodes with other observations (e.g. splat RGB -> state_dict)
    python -m gausstac_maniskill.replay --traj-path T.h5 --use-env-states -o state_dict --save-traj
    # check that the actions reproduce the episodes (success rate is printed)
    python -m gausstac_maniskill.replay --traj-path T.h5 -n 2
    # videos of the splat render camera
    python -m gausstac_maniskill.replay --traj-path T.h5 --use-env-states --save-video

What the launcher adds to ManiSkill's script:

* ``-c/--target-control-mode`` (action conversion) is refused with a clear message:
  ManiSkill converts only arm(+gripper) controllers, not a hand's single joint controller;
* no file is overwritten unless ``--overwrite`` is given. ManiSkill writes next to the source,
  ``<name>.<obs_mode>.<control_mode>.<sim_backend>.h5`` + ``.json`` (``<name>``: the source's
  file name up to its first dot; ``.<i>.h5`` + ``.json`` per worker of ``-n N`` on the CPU,
  merged into the first and deleted) and ``<k>.mp4`` videos, opening them for writing without
  a look at what is there: the launcher computes these names first (:func:`replay_outputs`) and
  refuses, before anything is written, when one exists, and always when one is the source;
* ``--save-video`` with ``-n N > 1`` on the CPU is refused: ManiSkill's workers all name their
  videos ``0.mp4``, ``1.mp4``, ... in the same folder and would overwrite each other's.
"""
from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass
from typing import Sequence

import gausstac_maniskill  # noqa: F401 - registers the GaussTac tasks: gym.make("GaussTac-...") works

from .errors import ConfigError

__all__ = ["main", "replayed_path", "replay_outputs", "check_outputs"]

#: ManiSkill's CPU backends (``mani_skill.envs.utils.system.backend.CPU_SIM_BACKENDS``) and the
#: names its envs give a backend (``sim_backend_name_mapping``): what the output's name holds.
_CPU_BACKENDS = ("cpu", "physx_cpu")
_BACKEND_NAMES = {"cpu": "physx_cpu", "cuda": "physx_cuda", "gpu": "physx_cuda",
                  "physx_cpu": "physx_cpu", "physx_cuda": "physx_cuda"}


def _source_json(traj_path: str) -> str:
    return traj_path.replace(".h5", ".json")  # as ManiSkill's replay finds it


def _source_meta(traj_path: str) -> dict:
    from mani_skill.utils import io_utils

    return io_utils.load_json(_source_json(traj_path))


def _default_modes(env_id: str, kw: dict) -> tuple[str, str]:
    """(obs_mode, control_mode) an env made with the recorded ``kw`` has when they name none:
    the control mode is the robot's first controller, known once the env exists, so one is made
    (on the CPU, without observations or rendering) and closed."""
    import gymnasium as gym

    kw = {k: v for k, v in kw.items() if k not in ("num_envs", "render_mode")}
    kw.update(num_envs=1, sim_backend="physx_cpu")
    obs_mode = kw.get("obs_mode")
    kw["obs_mode"] = "none"
    env = gym.make(env_id, **kw)
    try:
        u = env.unwrapped
        obs_mode = obs_mode or u.SUPPORTED_OBS_MODES[0]  # what BaseEnv picks for obs_mode=None
        return obs_mode, u.control_mode
    finally:
        env.close()


@dataclass
class _Plan:
    cpu: bool  # the CPU path of ManiSkill's main(): -n N is N worker processes
    outputs: list[str]


def _plan(args) -> _Plan:
    """What ManiSkill's ``replay_trajectory.main(args)`` does with its files, from its source
    (``main``, ``_main``, ``RecordEpisode``, ``BaseEnv``'s backend and obs-mode defaults)."""
    src = args.traj_path
    meta = _source_meta(src)
    info = meta["env_info"]
    kw = dict(info["env_kwargs"])
    # main(): the backend, and whether -n N runs N processes
    backend = args.sim_backend or kw.get("sim_backend") or "physx_cpu"
    if backend == "auto" and kw.get("num_envs", 1) == 1:
        backend = "physx_cpu"
    cpu = backend in _CPU_BACKENDS
    if not (args.save_traj or args.save_video):
        return _Plan(cpu, [])
    if backend == "auto":  # BaseEnv with num_envs = args.num_envs
        backend = "physx_cuda" if args.num_envs > 1 else "physx_cpu"
    backend = _BACKEND_NAMES.get(backend.split(":")[0], backend)
    # the env's obs_mode and control_mode
    obs_mode = args.obs_mode or kw.get("obs_mode")
    control = args.target_control_mode or kw.get("control_mode")
    if obs_mode is None or control is None:
        default_obs, default_control = _default_modes(info["env_id"], kw)
        obs_mode, control = obs_mode or default_obs, control or default_control
    # _main(): <source name up to its first dot>.<obs_mode>.<control_mode>.<backend>[.<proc>].h5 next to it
    folder = os.path.dirname(src)
    name = os.path.splitext(os.path.basename(src))[0].split(".")[0]
    stem = os.path.join(folder, f"{name}.{obs_mode}.{control}.{backend}")
    out = []
    if args.save_traj:
        out += [stem + ".h5", stem + ".json"]
        if cpu and args.num_envs > 1:  # each worker's file, merged into stem.h5 and deleted
            out += [f"{stem}.{i}{ext}" for i in range(args.num_envs) for ext in (".h5", ".json")]
    if args.save_video:
        episodes = len(meta["episodes"])
        count = episodes if args.count is None else min(args.count, episodes)
        # one video per replayed episode (CPU); on the GPU one per max_episode_steps steps: at most one
        # per batch of num_envs episodes, plus the one close() flushes
        videos = count if cpu else count + 1
        out += [os.path.join(folder, f"{k}.mp4") for k in range(videos)]
    return _Plan(cpu, out)


def replay_outputs(args) -> list[str]:
    """Every file ManiSkill's ``replay_trajectory.main(args)`` writes for parsed ``args``, all in
    the source's folder: with ``--save-traj`` first the ``.h5`` then its ``.json``, then per worker
    of ``-n N > 1`` on a CPU backend its ``.<i>.h5`` and ``.<i>.json``; with ``--save-video`` the
    ``<k>.mp4`` videos. Empty without ``--save-traj`` and ``--save-video``."""
    return _plan(args).outputs


def replayed_path(args) -> str:
    """The ``.h5`` ManiSkill's replay writes for parsed ``args`` (the merged one with ``-n > 1``);
    "" without ``--save-traj``."""
    return replay_outputs(args)[0] if args.save_traj else ""


def check_outputs(args, overwrite: bool = False) -> list[str]:
    """Raise :class:`ConfigError` if the replay of ``args`` would write over its source, over
    an existing file (unless ``overwrite``), or lose videos (``--save-video`` with ``-n > 1`` on
    the CPU); return the files it writes (:func:`replay_outputs`). Writes nothing."""
    plan = _plan(args)
    src = args.traj_path
    sources = [p for p in (src, _source_json(src)) if os.path.exists(p)]
    for p in plan.outputs:
        if os.path.exists(p) and any(os.path.samefile(p, s) for s in sources):
            raise ConfigError(
                f"--save-traj would write {p}, the file being replayed (ManiSkill names the output "
                "<name>.<obs_mode>.<control_mode>.<sim_backend>.h5 next to the source and truncates it before "
                "checking); pass another -o/--obs-mode, or copy the source (.h5 and .json) to another name first")
    if args.save_video and plan.cpu and args.num_envs > 1:
        raise ConfigError(
            f"--save-video with -n {args.num_envs} on the CPU: ManiSkill's worker processes all name their videos "
            f"0.mp4, 1.mp4, ... in {os.path.dirname(src) or '.'} and would overwrite each other's; use -n 1 "
            "for videos")
    existing = [p for p in plan.outputs if os.path.exists(p)]
    if existing and not overwrite:
        raise ConfigError(
            f"the replay would overwrite {', '.join(existing)}; nothing was written. ManiSkill writes next to the "
            f"source {src}: <first part of its name>.<obs_mode>.<control_mode>.<sim_backend>.h5 + .json"
            f"{' and <k>.mp4 videos' if args.save_video else ''}. Pass --overwrite to replace them, or move them "
            "away, or copy the source (.h5 and .json) to another folder and replay the copy")
    return plan.outputs


def _own_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    p.add_argument("--overwrite", action="store_true")
    return p


_OWN_HELP = ("gausstac_maniskill.replay adds:\n  --overwrite  replace the files the replay writes (--save-traj, "
             "--save-video) if they exist; without it the launcher refuses (never the source itself)\n"
             "  --add-tactile  add GaussTac touch to a stock task's trajectory (--add-tactile --help)\n")


def main(argv: Sequence[str] | None = None) -> int:
    from mani_skill.trajectory import replay_trajectory

    argv = list(sys.argv[1:] if argv is None else argv)
    if "--add-tactile" in argv:  # touch for a stock task's trajectory: our own parser, not ManiSkill's
        from .add_tactile import main as add_tactile_main

        return add_tactile_main([a for a in argv if a != "--add-tactile"])
    own, rest = _own_parser().parse_known_args(argv)
    if "-h" in rest or "--help" in rest:
        print(_OWN_HELP)
    args = replay_trajectory.parse_args(rest)
    for path in (args.traj_path, _source_json(args.traj_path)):
        if not os.path.exists(path):
            print(f"replay: error: {path} does not exist", file=sys.stderr)
            return 2
    if args.target_control_mode is not None:
        kw = _source_meta(args.traj_path)["env_info"]["env_kwargs"]
        if kw.get("control_mode") not in (None, args.target_control_mode):
            print(f"replay: error: -c/--target-control-mode {args.target_control_mode}: ManiSkill converts actions "
                  "only for robots with 'arm' (+ 'gripper') controllers; the GaussTac hands have one joint "
                  f"controller. Record again with `python -m gausstac_maniskill.collect ... -c "
                  f"{args.target_control_mode}`", file=sys.stderr)
            return 2
    try:
        check_outputs(args, overwrite=own.overwrite)
    except ConfigError as exc:
        print(f"replay: error: {exc}", file=sys.stderr)
        return 2
    replay_trajectory.main(args)
    return 0


if __name__ == "__main__":
    import multiprocessing as mp

    mp.set_start_method("spawn", force=True)  # as ManiSkill's script does; workers re-import this module
    sys.exit(main())
