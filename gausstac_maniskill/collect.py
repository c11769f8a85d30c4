"""Record scripted-expert demonstrations of a GaussTac task in ManiSkill's trajectory format.

``python -m gausstac_maniskill.collect GaussTac-PressCube-v1 --num-episodes 100 --num-procs 2``

Each worker process owns one env (``physx_cpu`` refuses ``num_envs > 1``: CPU
parallelism is one process per env) wrapped in ManiSkill's ``RecordEpisode``, drives it
with the task's scripted expert (:func:`gausstac_maniskill.experts.make_expert`) and
writes its own ``.h5`` + ``.json``; the parent shows one progress bar over all episodes
and at the end merges the worker files into one (traj ids renumbered in seed order),
gzip-compressing the large uncompressed datasets (mostly the co-simulation state).

With ``--ray [ADDRESS]`` the workers are Ray tasks (one CPU each) on a local Ray instance
or on a cluster; each records on its node and sends its files back through Ray's object
store, and the merged file is the one a local collection of the same seeds writes.

Episode ``i`` (0-based) is reset with seed ``seed + i`` and runs on worker ``i % num_procs``,
so the recorded seeds do not depend on the number of processes. With ``--only-success``
failed episodes are dropped and the worker goes on with further seeds (``i + num_procs``,
...) until it has its share of successes or ``--max-attempts`` times its share tried.

Output (ManiSkill's naming ``<name>.<obs_mode>.<control_mode>.<sim_backend>.h5``)::

    <out>/<env_id>/trajectory.rgb.pd_joint_delta_pos.physx_cpu.h5   (+ .json)
    <out>/<env_id>/videos/seed<seed>.mp4                           (--save-video)

A collection never replaces existing files silently: if the ``.h5``, its ``.json`` or one of
the videos it may write exists, it refuses before recording anything (:func:`existing_outputs`)
unless ``--overwrite`` is given.

Per trajectory ``traj_<n>``: ``actions [T, A]``, ``obs`` (``agent``, ``extra``,
``sensor_data/splat_camera/rgb [T+1, H, W, 3] uint8`` in rgb mode, and
``tactile/<pad>/depth [T+1, 16, 16]``, ``shear [T+1, 16, 16, 2]``, ``force [T+1, 16, 16]``),
``env_states`` (SAPIEN actors/articulations plus ``gausstac/*``: the co-simulation state, so that
``set_state_dict`` reproduces the tactile maps exactly), ``rewards``, ``success``,
``terminated``, ``truncated``. Replay with ``python -m gausstac_maniskill.replay``.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing as mp
import os
import queue as queue_mod
import shutil
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from . import environment
from .errors import ConfigError

__all__ = ["CollectConfig", "collect", "merge_trajectories", "output_path", "existing_outputs", "main"]


@dataclass
class CollectConfig:
    """What :func:`collect` records (see the module docstring and ``--help``)."""

    env_id: str
    num_episodes: int = 10
    num_procs: int = 1
    obs_mode: str = "rgb"
    control_mode: str | None = "pd_joint_delta_pos"
    seed: int = 0
    out: str = "demos"
    only_success: bool = False
    max_attempts: float = 3.0
    save_video: bool = False
    mpm_dx: float = 1.0e-3
    max_episode_steps: int | None = None
    record_mpm_state: bool = True
    compress: bool = True
    keep_worker_files: bool = False
    arch: str | None = None
    progress: bool = True
    env_kwargs: dict = field(default_factory=dict)
    #: run the workers as Ray tasks: ``"local"`` starts a Ray instance on this machine (or
    #: uses the one this process already joined), any other string is a cluster's address
    #: (``ray.init(address=...)``, e.g. ``"auto"`` or ``"ray://head:10001"``); None: processes
    ray: str | None = None
    #: replace the output files (.h5, .json, videos) if they exist; else :func:`collect` refuses
    overwrite: bool = False

    def validate(self) -> None:
        if not isinstance(self.env_id, str) or not self.env_id:
            raise ConfigError(f"env_id={self.env_id!r} must be a registered env id such as 'GaussTac-Gesture-v1'")
        if int(self.num_episodes) < 1:
            raise ConfigError(f"--num-episodes={self.num_episodes} must be >= 1")
        if int(self.num_procs) < 1:
            raise ConfigError(f"--num-procs={self.num_procs} must be >= 1")
        if self.max_attempts < 1:
            raise ConfigError(f"--max-attempts={self.max_attempts} must be >= 1")
        if self.max_episode_steps is not None and int(self.max_episode_steps) < 1:
            raise ConfigError(f"--max-episode-steps={self.max_episode_steps} must be >= 1")
        if self.arch not in (None, "cpu", "cuda", "auto"):
            raise ConfigError(f"--arch={self.arch!r} must be cpu, cuda or auto")

    def make_kwargs(self) -> dict:
        """Keyword arguments of ``gym.make`` (they end up in the json's ``env_kwargs``)."""
        kw = dict(obs_mode=self.obs_mode, sim_backend="physx_cpu", mpm_dx=float(self.mpm_dx))
        if self.control_mode:
            kw["control_mode"] = self.control_mode
        if not self.record_mpm_state:
            kw["record_mpm_state"] = False
        if self.save_video:
            kw["render_mode"] = "rgb_array"
        kw.update(self.env_kwargs)
        if self.max_episode_steps is not None:
            kw["max_episode_steps"] = int(self.max_episode_steps)
        return kw


def output_path(cfg: CollectConfig) -> Path:
    """The merged ``.h5``: ``--out`` itself if it ends with ``.h5``, else
    ``<out>/<env_id>/trajectory.<obs_mode>.<control_mode>.physx_cpu.h5``."""
    out = Path(cfg.out)
    if out.suffix == ".h5":
        return out
    control = cfg.control_mode or "default"
    return out / cfg.env_id / f"trajectory.{cfg.obs_mode}.{control}.physx_cpu.h5"


def _video_seeds(cfg: CollectConfig) -> list[int]:
    """The seeds whose videos ``cfg`` may write: every episode index a worker may try."""
    procs = min(cfg.num_procs, cfg.num_episodes)
    cfg = dataclasses.replace(cfg, num_procs=procs)
    return sorted(cfg.seed + k + attempt * procs for k in range(procs)
                  for attempt in range(_worker_episodes(cfg, k)[1]))


def existing_outputs(cfg: CollectConfig) -> list[Path]:
    """The files :func:`collect` would write for ``cfg`` that exist already: the merged ``.h5``,
    its ``.json`` and (``save_video``) the ``videos/seed<s>.mp4`` of the seeds it may try."""
    out = output_path(cfg)
    paths = [out, out.with_suffix(".json")]
    if cfg.save_video:
        paths += [out.parent / "videos" / f"seed{s}.mp4" for s in _video_seeds(cfg)]
    return [p for p in paths if p.exists()]


# ---------------------------------------------------------------------------- workers
def _worker_episodes(cfg: CollectConfig, worker: int) -> tuple[int, int]:
    """(episodes this worker must keep, episode indices it may try at most)."""
    share = len(range(worker, cfg.num_episodes, cfg.num_procs))
    tries = int(np.ceil(share * cfg.max_attempts)) if cfg.only_success else share
    return share, tries


def _run_worker(cfg: CollectConfig, worker: int, h5_path: str, report: Callable[[tuple], None]) -> None:
    """Record this worker's episodes into ``h5_path`` (+ .json); ``report`` gets one
    ``("episode", ...)`` tuple per finished episode."""
    from . import backend

    if cfg.arch is not None:
        backend.init(cfg.arch)
    import gausstac_maniskill  # noqa: F401 - gym.make("GaussTac-...") (spawned workers start bare)

    share, tries = _worker_episodes(cfg, worker)
    if share == 0:
        return
    _record(cfg, worker, share, tries, Path(h5_path), report)


def _record(cfg: CollectConfig, worker: int, share: int, tries: int, h5_path: Path, report) -> None:
    import gymnasium as gym
    import torch
    from mani_skill.utils.wrappers.record import RecordEpisode

    from .experts import make_expert

    env = gym.make(cfg.env_id, **cfg.make_kwargs())
    _pin_pad_solver(env)
    env = RecordEpisode(env, output_dir=str(h5_path.parent), trajectory_name=h5_path.stem,
                        save_video=cfg.save_video, save_on_reset=False, record_reward=True,
                        video_fps=int(getattr(env.unwrapped, "control_freq", 20)),
                        source_type="scripted",
                        source_desc=f"gausstac_maniskill.experts scripted expert for {cfg.env_id}")
    if cfg.save_video:  # RecordEpisode writes videos to its output_dir; ours go to <out>/videos
        env.output_dir = h5_path.parent.parent / "videos"
        env.output_dir.mkdir(parents=True, exist_ok=True)
    expert = make_expert(env)
    kept = 0
    try:
        for attempt in range(tries):
            if kept >= share:
                break
            index = worker + attempt * cfg.num_procs
            seed = cfg.seed + index
            t0 = time.perf_counter()
            obs, info = env.reset(seed=seed)
            expert.reset()
            steps, success = 0, False
            while True:
                action = expert.act(obs)
                obs, _, terminated, truncated, info = env.step(action)
                steps += 1
                if bool(torch.as_tensor(terminated).any()) or bool(torch.as_tensor(truncated).any()):
                    break
            success = bool(torch.as_tensor(info.get("success", False)).any())
            keep = success or not cfg.only_success
            env.flush_trajectory(save=keep)
            if cfg.save_video:
                env.flush_video(name=f"seed{seed}", save=keep)
            kept += int(keep)
            report(("episode", worker, index, seed, success, keep, steps, time.perf_counter() - t0))
    finally:
        env.close()


def _pin_pad_solver(env) -> None:
    """Write the pads' solver the task resolved (``pad_solver="auto"``: ``"fem"`` or ``"mpm"``)
    into the env's spec, whose kwargs ``RecordEpisode`` stores as the json's ``env_kwargs``: the
    file names the solver behind its tactile maps, and a replay rebuilds the same pads whatever
    the tasks' default is by then."""
    import dataclasses

    u = env.unwrapped
    used = getattr(u, "pad_solver_used", None)
    if used is not None and u.spec is not None:
        u.spec = dataclasses.replace(u.spec, kwargs={**u.spec.kwargs, "pad_solver": used})


def _limit_threads(n: int) -> None:
    """A worker's share of the CPU: ``n`` threads for Taichi (before it starts) and torch."""
    import torch

    environment.write_default("GAUSSTAC_CPU_THREADS", str(n))
    torch.set_num_threads(n)


def _worker_entry(cfg: CollectConfig, worker: int, h5_path: str, q) -> None:
    """Process target: run the worker and report through the queue ``q``."""
    try:
        _limit_threads(max(1, (os.cpu_count() or 1) // cfg.num_procs))
        _run_worker(cfg, worker, h5_path, q.put)
        q.put(("done", worker, h5_path))
    except BaseException:  # noqa: BLE001 - the parent prints it and stops the others
        q.put(("error", worker, traceback.format_exc()))


# ---------------------------------------------------------------------------- merge
def _copy_group(src, dst, compression: str | None) -> None:
    """Copy an h5 group recursively; uncompressed datasets above 1 kB get ``compression``
    (with the shuffle filter), already-compressed ones are copied as they are."""
    import h5py

    for key, item in src.items():
        if isinstance(item, h5py.Group):
            _copy_group(item, dst.create_group(key, track_order=True), compression)
        elif compression is None or item.compression is not None or item.nbytes < 1024 or item.ndim == 0:
            src.copy(item, dst, name=key)
        else:
            dst.create_dataset(key, data=item[()], compression=compression, shuffle=True)
        for k, v in item.attrs.items():
            dst[key].attrs[k] = v


def merge_trajectories(out_h5: str | os.PathLike, inputs: Sequence[str | os.PathLike], *,
                       sort_by_seed: bool = True, compression: str | None = "gzip",
                       overwrite: bool = False) -> dict:
    """Merge ManiSkill trajectory files (``.h5`` + ``.json`` each) into ``out_h5`` (+ .json).

    Trajectories are renumbered ``traj_0 .. traj_{N-1}`` (and ``episode_id`` in the json)
    in ``episode_seed`` order (``sort_by_seed``) or in input order. The json keeps the
    first file's non-episode keys; files recorded from different envs or env kwargs are
    refused. Unlike ``mani_skill.trajectory.merge_trajectory.merge_trajectories`` (which
    copies groups as they are, in file order) this compresses the uncompressed datasets, and
    it refuses an ``out_h5`` (or its ``.json``) that exists unless ``overwrite``.

    Returns the merged json dict.
    """
    import h5py
    from mani_skill.utils.io_utils import dump_json, load_json

    inputs = [Path(p) for p in inputs]
    if not inputs:
        raise ConfigError("merge_trajectories: no input files")
    out_h5 = Path(out_h5)
    if any(p.resolve() == out_h5.resolve() for p in inputs if p.exists()):
        raise ConfigError(f"merge_trajectories: output {out_h5} is also an input")
    out_json = out_h5.with_suffix(".json")
    if not overwrite and (taken := [str(p) for p in (out_h5, out_json) if p.exists()]):
        raise ConfigError(f"merge_trajectories: {' and '.join(taken)} exist(s); pass overwrite=True to replace "
                          "it, or another output path")
    metas = []
    for p in inputs:
        jp = p.with_suffix(".json")
        if not p.exists() or not jp.exists():
            raise ConfigError(f"merge_trajectories: {p} or {jp} does not exist")
        metas.append(load_json(str(jp)))
    head = {k: v for k, v in metas[0].items() if k != "episodes"}
    for p, meta in zip(inputs[1:], metas[1:]):
        if meta.get("env_info") != head.get("env_info"):
            raise ConfigError(f"merge_trajectories: {p} was recorded with env_info {meta.get('env_info')}, "
                              f"{inputs[0]} with {head.get('env_info')}; refusing to merge them")
    entries = [(ep.get("episode_seed", 0) if sort_by_seed else 0, i, n, ep)
               for i, meta in enumerate(metas) for n, ep in enumerate(meta["episodes"])]
    entries.sort(key=lambda e: (e[0], e[1], e[2]))
    out_h5.parent.mkdir(parents=True, exist_ok=True)
    episodes = []
    files = [h5py.File(p, "r") for p in inputs]
    try:
        try:  # w-: fails if the file appeared since the check above
            dst_file = h5py.File(out_h5, "w" if overwrite else "w-")
        except FileExistsError as exc:
            raise ConfigError(f"merge_trajectories: {out_h5} exists; pass overwrite=True to replace it") from exc
        with dst_file as dst:
            for new_id, (_, i, _, ep) in enumerate(entries):
                name = f"traj_{ep['episode_id']}"
                if name not in files[i]:
                    raise ConfigError(f"merge_trajectories: {inputs[i]} has no group {name} listed in its json")
                _copy_group(files[i][name], dst.create_group(f"traj_{new_id}", track_order=True), compression)
                episodes.append({**ep, "episode_id": new_id})
    finally:
        for f in files:
            f.close()
    merged = {**head, "episodes": episodes}
    dump_json(str(out_json), merged, indent=2)
    return merged


# ---------------------------------------------------------------------------- driver
def collect(cfg: CollectConfig) -> dict:
    """Record ``cfg.num_episodes`` episodes; return the summary (also printed by :func:`main`)."""
    from tqdm import tqdm

    cfg.validate()
    from mani_skill.utils.registration import REGISTERED_ENVS

    import gausstac_maniskill
    from .experts import EXPERTS

    gausstac_maniskill.register()  # the GaussTac tasks into REGISTERED_ENVS

    if cfg.env_id not in REGISTERED_ENVS:
        raise ConfigError(f"unknown env id {cfg.env_id!r}; GaussTac envs: "
                          f"{sorted(e for e in REGISTERED_ENVS if e.startswith('GaussTac'))}")
    if cfg.env_id not in EXPERTS:
        raise ConfigError(f"no scripted expert for {cfg.env_id!r}; experts exist for {sorted(EXPERTS)}")
    out = output_path(cfg)
    if not cfg.overwrite and (taken := existing_outputs(cfg)):
        shown = ", ".join(map(str, taken[:4])) + (f" and {len(taken) - 4} more" if len(taken) > 4 else "")
        raise ConfigError(f"{shown} already exist(s): a collection there would replace it; nothing was "
                          "recorded. Pass --overwrite (CollectConfig(overwrite=True)) to replace it, or another "
                          "--out (a folder, or a .h5 path)")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.parent / f".{out.stem}.workers.{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    procs = min(cfg.num_procs, cfg.num_episodes)
    cfg = dataclasses.replace(cfg, num_procs=procs)
    paths = [str(tmp / f"worker{k}.h5") for k in range(procs)]
    records: list[tuple] = []
    t_start = time.perf_counter()
    bar = tqdm(total=cfg.num_episodes, unit="ep", desc=cfg.env_id, disable=not cfg.progress, dynamic_ncols=True)

    def on_episode(msg: tuple) -> None:  # ("episode", worker, index, seed, success, kept, steps, seconds)
        records.append(msg)
        if msg[5]:
            bar.update(1)
        bar.set_postfix(success=f"{sum(r[4] for r in records)}/{len(records)}", refresh=False)

    try:
        if cfg.ray is not None:
            _run_ray(cfg, paths, on_episode)
        elif procs == 1:  # in this process: no start-up cost, easier to debug
            _run_worker(cfg, 0, paths[0], on_episode)
        else:
            _run_processes(cfg, paths, on_episode)
    finally:
        bar.close()
    wall = time.perf_counter() - t_start
    inputs = [p for p in paths if Path(p).exists() and Path(p).with_suffix(".json").exists()]
    merged = {"episodes": []}
    if inputs:
        try:
            merged = merge_trajectories(out, inputs, compression="gzip" if cfg.compress else None,
                                        overwrite=cfg.overwrite)
        except ConfigError as exc:  # e.g. the output appeared during the recording: keep the episodes
            raise ConfigError(f"{exc}; the recorded episodes are kept in {tmp}") from exc
    if not cfg.keep_worker_files:
        shutil.rmtree(tmp, ignore_errors=True)
    kept = [r for r in records if r[5]]
    steps = sum(r[6] for r in kept)
    size = out.stat().st_size if out.exists() else 0
    summary = dict(
        env_id=cfg.env_id, path=str(out), episodes=len(merged["episodes"]), asked=cfg.num_episodes,
        attempted=len(records),
        success_rate=(sum(r[4] for r in records) / len(records)) if records else 0.0,
        steps=steps, mean_steps=steps / max(1, len(kept)),
        seconds_per_episode=float(np.mean([r[7] for r in records])) if records else 0.0,
        # without each worker's first episode (Taichi compiles kernels on first use)
        seconds_per_episode_warm=float(np.mean(warm)) if (warm := _warm_times(records)) else float("nan"),
        seconds_per_step=sum(r[7] for r in records) / max(1, sum(r[6] for r in records)),
        wall_seconds=wall, num_procs=procs, ray=cfg.ray, file_bytes=size, bytes_per_step=size / max(1, steps),
    )
    return summary


def _warm_times(records: list[tuple]) -> list[float]:
    first: dict[int, int] = {}
    for i, r in enumerate(records):
        first.setdefault(r[1], i)
    return [r[7] for i, r in enumerate(records) if i not in first.values()]


def _run_processes(cfg: CollectConfig, paths: list[str], on_episode) -> None:
    ctx = mp.get_context("spawn")  # fork would copy Taichi/SAPIEN state of the parent
    q = ctx.Queue()
    procs = [ctx.Process(target=_worker_entry, args=(cfg, k, paths[k], q), daemon=True)
             for k in range(len(paths))]
    for p in procs:
        p.start()
    done: set[int] = set()
    try:
        while len(done) < len(procs):
            try:
                msg = q.get(timeout=0.5)
            except queue_mod.Empty:
                for k, p in enumerate(procs):
                    if k not in done and not p.is_alive() and p.exitcode not in (0, None):
                        raise RuntimeError(f"collect worker {k} died with exit code {p.exitcode}")
                continue
            if msg[0] == "episode":
                on_episode(msg)
            elif msg[0] == "done":
                done.add(msg[1])
            elif msg[0] == "error":
                raise RuntimeError(f"collect worker {msg[1]} failed:\n{msg[2]}")
        for p in procs:
            p.join()
    finally:
        for p in procs:
            if p.is_alive():
                p.terminate()
                p.join(5)


def _ray_worker(cfg: CollectConfig, worker: int, queue) -> tuple[bytes, bytes] | None:
    """Ray task: record worker ``worker``'s episodes in a temporary folder of the node it runs
    on and return the ``.h5`` and ``.json`` bytes (the parent may be on another machine)."""
    import tempfile

    _limit_threads(1)  # one Ray CPU per worker
    with tempfile.TemporaryDirectory(prefix="gausstac_collect_") as tmp:
        h5_path = Path(tmp) / f"worker{worker}.h5"
        _run_worker(cfg, worker, str(h5_path), queue.put)
        if not h5_path.exists():
            return None
        return h5_path.read_bytes(), h5_path.with_suffix(".json").read_bytes()


def _run_ray(cfg: CollectConfig, paths: list[str], on_episode) -> None:
    """Run the workers as Ray tasks (one CPU each) on a local Ray instance or a cluster
    (``cfg.ray``); their episodes reach ``on_episode`` through a Ray queue, their files come
    back through Ray's object store and are written to ``paths``."""
    try:
        import ray
        from ray.util.queue import Empty, Queue
    except ImportError as exc:
        raise ConfigError("--ray needs Ray: pip install -e '.[ray]' (or pip install 'ray[default]')") from exc
    started = not ray.is_initialized()  # else: the Ray instance this process already joined
    if started:
        address = None if cfg.ray == "local" else cfg.ray
        try:  # the workers' own output (Taichi's banner, warnings) stays in Ray's logs
            ray.init(address=address, include_dashboard=False, log_to_driver=False, logging_level="WARNING")
        except (ConnectionError, RuntimeError, ValueError) as exc:
            raise ConfigError(f"--ray {cfg.ray}: could not reach a Ray cluster there ({exc})") from exc
    queue = Queue()
    task = ray.remote(num_cpus=1, max_retries=0)(_ray_worker)
    refs = {task.remote(cfg, k, queue): k for k in range(len(paths))}

    def drain(block: bool) -> None:
        while True:
            try:
                msg = queue.get(block=block, timeout=0.5 if block else None)
            except Empty:
                return
            on_episode(msg)
            block = False

    pending = list(refs)
    try:
        while pending:
            drain(block=True)
            finished, pending = ray.wait(pending, num_returns=len(pending), timeout=0)
            for ref in finished:
                k = refs[ref]
                try:
                    files = ray.get(ref)
                except ray.exceptions.RayError as exc:
                    raise RuntimeError(f"collect worker {k} failed on Ray:\n{exc}") from None
                if files is not None:
                    Path(paths[k]).write_bytes(files[0])
                    Path(paths[k]).with_suffix(".json").write_bytes(files[1])
        drain(block=False)
    finally:
        for ref in pending:  # after a failure: stop the others
            ray.cancel(ref, force=True)
        ray.kill(queue.actor)
        if started:
            ray.shutdown()


def _format_summary(s: dict) -> str:
    warm = s["seconds_per_episode_warm"]
    warm = "" if warm != warm else f" ({warm:.2f} s without each worker's first)"  # nan: one episode per worker
    return (f"{s['episodes']}/{s['asked']} episodes of {s['env_id']} ({s['attempted']} tried, success rate "
            f"{100 * s['success_rate']:.0f}%), {s['steps']} steps, {s['mean_steps']:.1f} steps/episode\n"
            f"{s['seconds_per_episode']:.2f} s per episode per worker{warm}, "
            f"{1000 * s['seconds_per_step']:.0f} ms/step, "
            f"{s['wall_seconds']:.1f} s wall with {s['num_procs']} "
            f"{'process(es)' if s.get('ray') is None else 'Ray worker(s) at ' + s['ray']}\n"
            f"{s['path']}: {s['file_bytes'] / 1e6:.2f} MB ({s['bytes_per_step'] / 1e3:.1f} kB/step)")


def _parse_kv(items: Sequence[str]) -> dict:
    out = {}
    for item in items:
        if "=" not in item:
            raise ConfigError(f"--env-kwarg {item!r} must look like key=value (value as JSON or a string)")
        k, v = item.split("=", 1)
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gausstac_maniskill.collect", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("env_id", help="task id, e.g. GaussTac-PressCube-v1")
    p.add_argument("-n", "--num-episodes", type=int, default=10, help="episodes to record (default 10)")
    p.add_argument("-p", "--num-procs", type=int, default=1, help="worker processes, one env each (default 1)")
    p.add_argument("-o", "--obs-mode", default="rgb",
                   help="ManiSkill obs mode: rgb (default: splat camera RGB + state + tactile), state_dict, ...")
    p.add_argument("-c", "--control-mode", default="pd_joint_delta_pos",
                   help="pd_joint_delta_pos (default; normalized [-1, 1] actions as ManiSkill's DP/BC expect) "
                        "or pd_joint_pos")
    p.add_argument("-s", "--seed", type=int, default=0, help="episode i is reset with seed + i (default 0)")
    p.add_argument("--out", default="demos", help="output folder (<out>/<env_id>/trajectory.*.h5) or a .h5 path")
    p.add_argument("--only-success", action="store_true", help="keep successful episodes only (tries more seeds)")
    p.add_argument("--max-attempts", type=float, default=3.0,
                   help="with --only-success: give up after this many times the episodes asked for (default 3)")
    p.add_argument("--save-video", action="store_true", help="also write <out>/<env_id>/videos/seed<s>.mp4")
    p.add_argument("--mpm-dx", type=float, default=1.0e-3, help="MPM grid spacing [m] (default 1e-3: the 4 mm pads span 4 cells)")
    p.add_argument("--max-episode-steps", type=int, default=None, help="override the task's time limit")
    p.add_argument("--no-mpm-state", action="store_true",
                   help="leave the MPM state out of env_states (smaller files; replay by states then "
                        "restarts the pads at rest and is not exact)")
    p.add_argument("--no-compress", action="store_true", help="do not gzip the merged file's datasets")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing output (.h5, .json, videos); without it collect refuses to start")
    p.add_argument("--keep-worker-files", action="store_true", help="keep the per-worker .h5/.json")
    p.add_argument("--arch", choices=["cpu", "cuda", "auto"], default=None,
                   help="Taichi backend of the workers (default: $GAUSSTAC_ARCH or auto)")
    p.add_argument("--env-kwarg", action="append", default=[], metavar="KEY=VALUE",
                   help="extra gym.make keyword (value parsed as JSON), repeatable")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                   help="run the --num-procs workers as Ray tasks (pip install -e '.[ray]'): on a local Ray "
                        "instance, or on the cluster at ADDRESS ('auto' when this machine is a cluster node, "
                        "'ray://<head>:10001' from outside); every node needs this package installed")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    cfg = CollectConfig(env_id=args.env_id, num_episodes=args.num_episodes, num_procs=args.num_procs,
                        obs_mode=args.obs_mode, control_mode=args.control_mode, seed=args.seed, out=args.out,
                        only_success=args.only_success, max_attempts=args.max_attempts,
                        save_video=args.save_video, mpm_dx=args.mpm_dx, max_episode_steps=args.max_episode_steps,
                        record_mpm_state=not args.no_mpm_state, compress=not args.no_compress,
                        keep_worker_files=args.keep_worker_files, arch=args.arch,
                        progress=not args.no_progress, env_kwargs=_parse_kv(args.env_kwarg), ray=args.ray,
                        overwrite=args.overwrite)
    try:
        summary = collect(cfg)
    except ConfigError as exc:
        print(f"collect: error: {exc}", file=sys.stderr)
        return 2
    print(_format_summary(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
