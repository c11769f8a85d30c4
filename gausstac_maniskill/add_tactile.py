"""Add touch to a trajectory recorded on a stock ManiSkill task.

``python -m gausstac_maniskill.replay --add-tactile --traj-path T.h5 [--out NEW.h5] [--mpm-dx 1e-3]
[--count N] [--overwrite]``

``T.h5`` (+ ``T.json``) is a ManiSkill trajectory (``RecordEpisode``, ``replay_trajectory``) recorded
on a stock task that :func:`~gausstac_maniskill.make_tactile` gives pads (``RotateValveLevel0-v1``,
``TriFingerRotateCubeLevel0-v1``, ``RotateSingleObjectInHandLevel0-v1``, ...) with its env states
(``traj_<i>/env_states``: SAPIEN actors and articulations, ``[T+1, D]`` per leaf). The recorded
task is made again with pads (``make_tactile(env_id, obs_mode="state_dict", **recorded env
kwargs, mpm_dx=...)``) and every episode is reset with its recorded reset kwargs (seed, options)
and then driven by its states: the SAPIEN state drives the hand and the objects, and the pads
follow.

* step 0: the state ``env_states[0]`` is set with the env's ``set_state_dict`` (no ``"gausstac"``
  part: the co-simulators are built at rest from its poses), the maps read;
* step t > 0: ManiSkill's ``set_state_dict`` (the stock task's, SAPIEN only: the co-simulators
  are kept) sets ``env_states[t]``, then the co-simulator advances one control step
  (``control_timestep`` s) from the previous poses to these (``GaussTacEnv._step_mpm``), so the
  pads' friction history carries from step to step, and ``get_obs()["tactile"]`` is read.

The pads do not act back on SAPIEN: the recorded states are what the stock simulation did (no pads
touched it). A live ``make_tactile`` run of tasks without two-way objects (the DClaw valve) steps
its pads the same way, once per control step, from the same poses: the maps agree (to float
rounding of the recorded poses). With two-way objects (the Allegro cube, the TriFinger cube) the
live run steps the pads after every SAPIEN substep and pushes the object with their reaction; here
they step once per control step, between the recorded poses (the substep path is not recorded).

Limitation: what the pads feel here is how far the recorded objects reach into them, and a stock
recording keeps the stock hand's clearance. SAPIEN stopped the objects at the stock colliders:
on the Allegro (touch) hand the tip hull, which is the pads' outer surface (and the stock tip FSR
boxes standing up to 2 mm out of it); on the DClaw the stock tip hull, wider than the finger the
pads are cut from. The twin's rigid core lies about 3 mm under the pads' surface, so live
``make_tactile`` runs press into the pads, stock recordings barely or not at all: maps of stock data
are mostly zero. Per trajectory and pad, the json's ``env_info["gausstac"]["contact"]`` gives
the max total force [N] and the number of frames with force > 0.

Output: a NEW ``.h5`` (default ``<source without .h5>.tactile.h5`` next to it) that is the source
copied plus, per trajectory, ``traj_<i>/obs/tactile/<pad>/<map>`` float32 datasets (gzip) of
``T+1`` frames: ``depth [T+1, H, W]`` m, ``shear [T+1, H, W, 2]`` m, ``force [T+1, H, W]`` N
(and ``pressure [T+1, H, W]`` Pa where the pads give it), frame t read after state t; and its
``.json``, the source's with ``env_info["gausstac"] = {"pads": [...], "mpm_dx": ..., ...}``. The
source is only read. An existing output is refused unless ``--overwrite`` (the source never).
"""
from __future__ import annotations

import argparse
import copy
import json
import os
import shutil
import sys
from typing import Sequence

import numpy as np

from .errors import ConfigError

__all__ = ["add_tactile", "tactile_outputs", "check_tactile_outputs", "stock_state", "main"]

#: the default pads' MPM grid spacing [m] (GaussTacEnv's default)
DEFAULT_MPM_DX = 1.0e-3
#: env kwargs of the recording that are not passed on (the replay sets its own)
_DROPPED_KWARGS = ("obs_mode", "num_envs", "render_mode", "sim_backend", "mpm_dx")


def _json_of(h5_path: str) -> str:
    return h5_path[:-3] + ".json" if h5_path.endswith(".h5") else h5_path + ".json"


def tactile_outputs(traj_path: str, out: str | None = None) -> list[str]:
    """``[output .h5, its .json]`` of adding touch to ``traj_path``: ``out`` (must end in
    ``.h5``) or ``<traj_path without .h5>.tactile.h5``, the json next to it."""
    if out is None:
        out = (traj_path[:-3] if traj_path.endswith(".h5") else traj_path) + ".tactile.h5"
    if not out.endswith(".h5"):
        raise ConfigError(f"--out {out}: the output is a ManiSkill trajectory, name it <name>.h5 "
                          "(its json is <name>.json)")
    return [out, _json_of(out)]


def check_tactile_outputs(traj_path: str, out: str | None = None, overwrite: bool = False) -> list[str]:
    """Raise :class:`ConfigError` if adding touch to ``traj_path`` would write over its source
    (always) or over an existing file (unless ``overwrite``), or if the source is missing;
    return the files it writes (:func:`tactile_outputs`). Writes nothing."""
    outputs = tactile_outputs(traj_path, out)
    sources = [traj_path, _json_of(traj_path)]
    for p in sources:
        if not os.path.exists(p):
            raise ConfigError(f"add-tactile: {p} does not exist (the source trajectory is <name>.h5 + <name>.json)")
    for p in outputs:
        if os.path.exists(p) and any(os.path.samefile(p, s) for s in sources):
            raise ConfigError(f"add-tactile would write {p}, the file it reads; the source is never changed: "
                              "pass another --out")
    existing = [p for p in outputs if os.path.exists(p)]
    if existing and not overwrite:
        raise ConfigError(
            f"add-tactile would overwrite {', '.join(existing)}; nothing was written. It writes a new trajectory "
            f"(the source {traj_path} copied plus traj_<i>/obs/tactile) to --out, by default <source name>."
            "tactile.h5 + .json next to the source. Pass --overwrite to replace them, or another --out, or move "
            "them away")
    return outputs


def stock_state(state: dict, robot: str, stock_robot: str) -> dict:
    """The stock task's part of a state dict of a ``make_tactile`` env: ``actors`` and
    ``articulations`` only (no ``"gausstac"`` co-simulation state, no ``"task"``), the twin
    hand's articulation ``robot`` renamed ``stock_robot`` (leaves copied, shapes kept)."""
    arts = {(stock_robot if k == robot else k): np.array(v) for k, v in state.get("articulations", {}).items()}
    return {"actors": {k: np.array(v) for k, v in state.get("actors", {}).items()}, "articulations": arts}


def _twin_state(state: dict, u, stock_robot: str, where: str) -> dict:
    """A recorded stock state (``{"actors": {name: [D]}, "articulations": {name: [D]}}``) as the
    tactile env ``u`` names it: the stock hand's articulation under the twin's name; every other
    key must match those of the env's own state dict (its non-static actors, its articulations)."""
    robot = u.agent.robot.name
    arts = dict(state.get("articulations", {}))
    if robot not in arts and stock_robot in arts:
        arts[robot] = arts.pop(stock_robot)
    out = {"actors": dict(state.get("actors", {})), "articulations": arts}
    from .tasks.base import GaussTacEnv

    have = super(GaussTacEnv, u).get_state_dict()  # the stock part of the env's own state (no static actors)
    for part in ("actors", "articulations"):
        rec, live = set(out[part]), set(have.get(part, {}))
        if rec != live:
            raise ConfigError(f"add-tactile: {where}: the recorded {part} {sorted(rec)} are not the tactile task's "
                              f"{sorted(live)} (missing {sorted(live - rec)}, extra {sorted(rec - live)}); was it "
                              "recorded on this task and ManiSkill version?")
    return out


def _load_group(g) -> dict:
    import h5py

    return {k: (_load_group(v) if isinstance(v, h5py.Group) else v[()]) for k, v in g.items()}


def _index(x: dict, t: int) -> dict:
    return {k: (_index(v, t) if isinstance(v, dict) else v[t]) for k, v in x.items()}


def _length(x: dict) -> int:
    for v in x.values():
        return _length(v) if isinstance(v, dict) else len(v)
    return 0


def _reset_kwargs(episode: dict) -> dict:
    """The episode's reset kwargs with its seed, as ManiSkill's replay formats them."""
    kw = copy.deepcopy(episode.get("reset_kwargs", {}))
    seed = kw.get("seed", episode.get("episode_seed"))
    if isinstance(seed, list):
        if len(seed) != 1:
            raise ConfigError(f"add-tactile: episode {episode.get('episode_id')} has {len(seed)} reset seeds; "
                              "one env per episode is replayed")
        seed = seed[0]
    if seed is not None:
        kw["seed"] = seed
    return kw


def make_env(meta: dict, mpm_dx: float):
    """The recorded task of ``meta`` (the source json) with pads: ``make_tactile(env_id,
    obs_mode="state_dict", num_envs=1, sim_backend="physx_cpu", **recorded env kwargs,
    mpm_dx=mpm_dx)``, and the stock hand's articulation name."""
    from mani_skill.utils.registration import REGISTERED_ENVS

    from .stock_tasks import make_tactile, twin_agent

    info = meta["env_info"]
    env_id = info["env_id"]
    from ._registry import register_with_maniskill

    register_with_maniskill()
    import mani_skill.envs  # noqa: F401 - registers ManiSkill's tasks

    from .tasks.base import GaussTacEnv

    spec = REGISTERED_ENVS.get(env_id)
    if spec is not None and issubclass(spec.cls, GaussTacEnv):
        raise ConfigError(f"add-tactile: {env_id} is a GaussTac task, its trajectories have touch already (replay "
                          "them with python -m gausstac_maniskill.replay --use-env-states)")
    kw = {k: v for k, v in dict(info.get("env_kwargs", {})).items() if k not in _DROPPED_KWARGS}
    env = make_tactile(env_id, obs_mode="state_dict", num_envs=1, sim_backend="physx_cpu", mpm_dx=mpm_dx, **kw)
    u = env.unwrapped
    stock_robot = u.robot_uids if isinstance(u.robot_uids, str) else twin_agent(u.robot_uids).__bases__[-1].uid
    return env, stock_robot


def replay_episode(env, states: dict, stock_robot: str, reset_kwargs: dict, where: str = "", pbar=None) -> dict:
    """Drive the tactile ``env`` by one episode's recorded stock states and read its maps.

    Args:
        env: a ``make_tactile`` env (one env, ``obs_mode="state_dict"``).
        states: ``{"actors": {name: [T+1, D]}, "articulations": {name: [T+1, D]}}`` arrays.
        stock_robot: the stock hand's articulation name in ``states``.
        reset_kwargs: ``env.reset`` kwargs (``seed``, ``options``).
    Returns:
        ``{pad: {map: [T+1, H, W(, 2)] float32 ndarray}}``: depth [m], shear [m], force [N],
        pressure [Pa] (those the pads give), frame t read after state t.
    """
    from .tasks.base import GaussTacEnv

    u = env.unwrapped
    env.reset(**reset_kwargs)
    frames: dict[str, dict[str, list]] = {}
    for t in range(_length(states)):
        state = _twin_state(_index(states, t), u, stock_robot, f"{where} step {t}")
        if t == 0:
            u.set_state_dict(state)  # no "gausstac": the co-simulators are built at rest from these poses
        else:
            super(GaussTacEnv, u).set_state_dict(batch(state))  # SAPIEN only (the stock task's): pads carried
            u._step_mpm(u.control_timestep)  # the pads follow, over one control step
        for pad, maps in u.get_obs(unflattened=True)["tactile"].items():
            for key, m in maps.items():
                frames.setdefault(pad, {}).setdefault(key, []).append(m[0].detach().cpu().numpy().astype(np.float32))
        if pbar is not None:
            pbar.update(1)
    return {pad: {k: np.stack(v) for k, v in maps.items()} for pad, maps in frames.items()}


def batch(state: dict) -> dict:
    """One env's state (leaves ``[D]``) with the env axis (``[1, D]``)."""
    from .tactile_env import batch_state

    return batch_state(state)


def add_tactile(traj_path: str, out: str | None = None, *, mpm_dx: float = DEFAULT_MPM_DX, overwrite: bool = False,
                count: int | None = None, progress: bool = True) -> list[str]:
    """Write ``traj_path`` (a stock task's trajectory) copied plus ``traj_<i>/obs/tactile`` to a new
    file (see the module docstring); return ``[out .h5, out .json]``.

    Args:
        traj_path: the source ``.h5`` (its ``.json`` next to it); only read.
        out: the output ``.h5`` (default ``<traj_path without .h5>.tactile.h5``).
        mpm_dx: the pads' MPM grid spacing [m].
        overwrite: replace an existing output (never the source).
        count: only the first ``count`` episodes of the json get maps (the rest are copied as they are).
        progress: a tqdm bar over the replayed steps.
    Raises:
        ConfigError: the output exists (without ``overwrite``) or is the source; the task is a
            GaussTac task or has no hand with pads; a trajectory lacks ``env_states``, has
            ``obs/tactile`` already, or has flat ``obs`` (``obs_mode="state"``).
    """
    import h5py
    from mani_skill.utils.io_utils import dump_json, load_json
    from tqdm import tqdm

    out_h5, out_json = check_tactile_outputs(traj_path, out, overwrite)
    meta = load_json(_json_of(traj_path))
    episodes = meta["episodes"] if count is None else meta["episodes"][:count]
    with h5py.File(traj_path, "r") as src:
        names = []
        for ep in episodes:
            name = f"traj_{ep['episode_id']}"
            if name not in src:
                raise ConfigError(f"add-tactile: {traj_path} has no group {name} listed in its json")
            g = src[name]
            if "env_states" not in g:
                raise ConfigError(f"add-tactile: {traj_path}/{name} has no env_states (record with "
                                  "RecordEpisode(record_env_state=True), ManiSkill's default)")
            if "obs" in g and not isinstance(g["obs"], h5py.Group):
                raise ConfigError(f"add-tactile: {traj_path}/{name}/obs is a flat array (obs_mode 'state'); the maps "
                                  "go to obs/tactile/<pad>/<map>: replay it with -o state_dict or none first")
            if "obs" in g and "tactile" in g["obs"]:
                raise ConfigError(f"add-tactile: {traj_path}/{name}/obs/tactile exists already")
            names.append(name)
        total = sum(_length(src[n]["env_states"]) for n in names)
    env, stock_robot = make_env(meta, mpm_dx)
    part = out_h5 + ".part"
    try:
        u = env.unwrapped
        shutil.copyfile(traj_path, part)
        bar = tqdm(total=total, desc="add-tactile", unit="step", disable=not progress)
        shapes, contact = {}, {}
        with h5py.File(part, "r+") as dst, h5py.File(traj_path, "r") as src:
            for ep, name in zip(episodes, names):
                bar.set_description(f"add-tactile {name}")
                states = _load_group(src[name]["env_states"])
                maps = replay_episode(env, states, stock_robot, _reset_kwargs(ep), f"{traj_path}/{name}", bar)
                obs = dst[name].require_group("obs")
                tac = obs.create_group("tactile", track_order=True)
                for pad, per in maps.items():
                    pg = tac.create_group(pad, track_order=True)
                    for key, arr in per.items():
                        pg.create_dataset(key, data=arr, compression="gzip", shuffle=True)
                        shapes.setdefault(pad, {})[key] = list(arr.shape[1:])
                total_force = {pad: per["force"].reshape(len(per["force"]), -1).sum(1) for pad, per in maps.items()}
                contact[name] = {pad: {"max_force_N": float(f.max()), "frames_touched": int((f > 0).sum()),
                                       "frames": int(len(f))} for pad, f in total_force.items()}
        bar.close()
        meta = copy.deepcopy(meta)
        meta["env_info"]["gausstac"] = {
            "pads": list(u.pad_names), "mpm_dx": float(mpm_dx), "pad_solver": getattr(u, "pad_solver_used", None),
            "maps": shapes, "units": {"depth": "m", "shear": "m", "force": "N", "pressure": "Pa"},
            "added_to": os.path.basename(traj_path), "tactile_env_id": u.spec.id if u.spec else None,
            "stepping": f"SAPIEN state set from env_states[t], pads advanced once per control step "
                        f"({u.control_timestep} s), at rest at t=0",
            "episodes_with_tactile": [ep["episode_id"] for ep in episodes],
            "contact": contact}  # per trajectory and pad: max total force [N], frames with force > 0
        os.replace(part, out_h5)
        dump_json(out_json, meta, indent=2)
    finally:
        env.close()
        if os.path.exists(part):
            os.remove(part)
    return [out_h5, out_json]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gausstac_maniskill.replay --add-tactile",
                                description="Add GaussTac touch (obs/tactile) to a trajectory recorded on a stock "
                                            "ManiSkill task, driven by its env states; writes a new file.")
    p.add_argument("--traj-path", required=True, help="the source .h5 (its .json next to it); only read")
    p.add_argument("--out", default=None, help="the output .h5 (default <source without .h5>.tactile.h5)")
    p.add_argument("--mpm-dx", type=float, default=DEFAULT_MPM_DX, help="the pads' MPM grid spacing [m]")
    p.add_argument("--count", type=int, default=None, help="only the first N episodes")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output (never the source)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(list(sys.argv[1:] if argv is None else argv))
    try:
        out = add_tactile(args.traj_path, args.out, mpm_dx=args.mpm_dx, overwrite=args.overwrite,
                          count=args.count, progress=not args.no_progress)
    except ConfigError as exc:
        print(f"replay: error: {exc}", file=sys.stderr)
        return 2
    from mani_skill.utils.io_utils import load_json

    contact = load_json(out[1])["env_info"]["gausstac"]["contact"]
    touched = sum(c["frames_touched"] for per in contact.values() for c in per.values())
    print(json.dumps({"h5": out[0], "json": out[1], "pad_frames_touched": touched}))
    if touched == 0:
        print("replay: note: no pad felt anything in any frame. The recorded SAPIEN states keep the stock hand's "
              "clearance: objects stop at the stock colliders, which lie on or outside the pads' surface (the pads "
              "are cut from the tip hull, their rigid core inset under it), so they are rarely indented. See "
              "gausstac_maniskill.add_tactile's docstring", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
