"""ManiSkill's ``replay_trajectory`` with the GaussTac tasks registered.

``python -m gausstac_maniskill.replay --traj-path demos/.../trajectory.rgb.pd_joint_delta_pos.physx_cpu.h5 [args]``

The arguments are those of ``python -m mani_skill.trajectory.replay_trajectory``
(``--help`` lists them); the launcher imports :mod:`gausstac_maniskill` first so
that ``gym.make("GaussTac-...")`` works, also in the worker processes of ``-n N`` (they
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
* ``--save-traj`` that would overwrite the source is refused: ManiSkill names the output
  ``<name>.<obs_mode>.<control_mode>.<sim_backend>.h5`` next to the source and opens it for
  writing before checking that it is not the source.
"""
from __future__ import annotations

import os
import sys
from typing import Sequence

import gausstac_maniskill  # noqa: F401 - registers the GaussTac tasks: gym.make("GaussTac-...") works

__all__ = ["main", "replayed_path"]


def replayed_path(args) -> str:
    """The ``.h5`` ManiSkill's replay writes for parsed ``args`` (before ``_main``'s ``.<proc>``
    suffix for ``-n > 1``, which merges back to this name)."""
    from mani_skill.utils import io_utils

    src = args.traj_path
    info = io_utils.load_json(src.replace(".h5", ".json"))["env_info"]
    kw = info["env_kwargs"]
    obs_mode = args.obs_mode or kw.get("obs_mode") or "state"
    control = args.target_control_mode or kw.get("control_mode")
    backend = args.sim_backend or kw.get("sim_backend") or "physx_cpu"
    if control is None:
        return ""  # the env default: only known once the env exists; ManiSkill's own check applies
    name = os.path.splitext(os.path.basename(src))[0].split(".")[0]
    return os.path.join(os.path.dirname(src), f"{name}.{obs_mode}.{control}.{backend}.h5")


def main(argv: Sequence[str] | None = None) -> int:
    from mani_skill.trajectory import replay_trajectory

    args = replay_trajectory.parse_args(list(sys.argv[1:] if argv is None else argv))
    if not os.path.exists(args.traj_path):
        print(f"replay: error: {args.traj_path} does not exist", file=sys.stderr)
        return 2
    if args.target_control_mode is not None:
        from mani_skill.utils import io_utils

        kw = io_utils.load_json(args.traj_path.replace(".h5", ".json"))["env_info"]["env_kwargs"]
        if kw.get("control_mode") not in (None, args.target_control_mode):
            print(f"replay: error: -c/--target-control-mode {args.target_control_mode}: ManiSkill converts actions "
                  "only for robots with 'arm' (+ 'gripper') controllers; the GaussTac hands have one joint "
                  f"controller. Record again with `python -m gausstac_maniskill.collect ... -c "
                  f"{args.target_control_mode}`", file=sys.stderr)
            return 2
    if args.save_traj:
        target = replayed_path(args)
        if target and os.path.exists(target) and os.path.samefile(target, args.traj_path):
            print(f"replay: error: --save-traj would write {target}, the file being replayed (ManiSkill names "
                  "the output <name>.<obs_mode>.<control_mode>.<sim_backend>.h5); pass another -o/--obs-mode, "
                  "or copy the source to another name first", file=sys.stderr)
            return 2
    replay_trajectory.main(args)
    return 0


if __name__ == "__main__":
    import multiprocessing as mp

    mp.set_start_method("spawn", force=True)  # as ManiSkill's script does; workers re-import this module
    sys.exit(main())
