"""``python -m gausstac_maniskill.bench scale [--tasks ID ...] [--envs 1 16 64 256] [--obs state_dict rgb]
[--backend physx_cuda]``
— env-steps per second of GaussTac tasks with ``num_envs = B`` on one simulator.

Per task, obs mode and B: build time, ms per control step split by ``GaussTacEnv.step_timing``
(physics, mpm, tactile, render), env-steps/s and the limiting part, over up to ``--steps`` steps
or ``--budget`` seconds after ``--warmup`` untimed steps; writes ``scale.md`` and ``scale.json``.
``num_envs > 1`` needs ``physx_cuda`` (an NVIDIA GPU); ``--backend physx_cpu --envs 1`` runs the
same path for one env.
"""
from __future__ import annotations

import os
import time
import traceback

from .common import STEP_PARTS, cli, step_split_ms, write_json, write_report

TASKS = ("GaussTac-PressCube-v1", "GaussTac-SqueezeSponge-v1")
PARTS = STEP_PARTS[:-1]  # without the total


def run(env_id: str, num_envs: int, obs_mode: str, sim_backend: str, steps: int, warmup: int,
        budget: float) -> dict:
    """One run (see the module docstring): build time [s], timed steps, mean ms per part."""
    import gymnasium as gym

    from ..experts import make_expert

    t0 = time.perf_counter()
    env = gym.make(env_id, num_envs=num_envs, obs_mode=obs_mode, sim_backend=sim_backend,
                   control_mode="pd_joint_pos")
    try:
        obs, _ = env.reset(seed=0)
        base = env.unwrapped
        expert = make_expert(env)
        expert.reset()
        build = time.perf_counter() - t0
        rows, info = [], {}
        t_start = None
        for k in range(warmup + steps):
            obs, _, _, _, info = env.step(expert.act(obs))
            if k < warmup:
                continue
            rows.append(dict(base.step_timing))
            t_start = t_start or time.perf_counter()
            if time.perf_counter() - t_start > budget:
                break
        last = base.mpm_world.last_step
        particles = 0 if last is None else last.active_particles
        out = step_split_ms(rows)
        success = info.get("success")
        out.update(build=build, steps=len(rows), particles=particles,
                   success=None if success is None else float(success.float().mean()))
        return out
    finally:
        env.close()


def _row(env_id, obs_mode, B, r) -> str:
    if "error" in r:
        return f"| {env_id} | {obs_mode} | {B} | failed: {r['error']} |"
    limit = max(PARTS, key=lambda p: r[p])
    succ = "-" if r["success"] is None else f"{r['success']:.2f}"
    return (f"| {env_id} | {obs_mode} | {B} | {r['build']:.0f} | {r['particles']} | {r['steps']} | "
            f"{r['total']:.0f} | {r['physics']:.0f} | {r['mpm']:.0f} | {r['tactile']:.0f} | {r['render']:.0f} | "
            f"**{B / r['total'] * 1e3:.1f}** | {limit} | {succ} |")


HEADER = ("| task | obs | B | build [s] | active particles | timed steps | step [ms] | physics | MPM | tactile | "
          "render | env-steps/s | limited by | success (last step) |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")


def main(argv: list[str] | None = None) -> int:
    ap = cli("scale", __doc__)
    ap.add_argument("--tasks", nargs="+", default=list(TASKS), metavar="ENV_ID")
    ap.add_argument("--envs", type=int, nargs="+", default=[1, 16, 64, 256], help="env counts B")
    ap.add_argument("--obs", nargs="+", default=["state_dict", "rgb"], help="obs modes")
    ap.add_argument("--backend", default="physx_cuda", help="ManiSkill sim_backend (default: physx_cuda)")
    ap.add_argument("--steps", type=int, default=10, help="timed control steps per run, at most")
    ap.add_argument("--warmup", type=int, default=2, help="untimed control steps first")
    ap.add_argument("--budget", type=float, default=30.0, help="seconds of timed steps per run, at most")
    ap.add_argument("--out", default="out/bench_scale")
    args = ap.parse_args(argv)
    import platform

    from .. import backend

    arch = backend.ensure_init()
    import torch

    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "no CUDA device"
    print(f"[bench scale] Taichi {arch}, ManiSkill {args.backend}, {gpu}, {platform.machine()} "
          f"{os.cpu_count()} cores", flush=True)
    print(HEADER, flush=True)
    results = []
    for env_id in args.tasks:
        for B in args.envs:  # small B first: a run cut short still leaves every obs mode's small rows
            for obs_mode in args.obs:
                try:
                    r = run(env_id, B, obs_mode, args.backend, args.steps, args.warmup, args.budget)
                except Exception as err:  # noqa: BLE001 - a failed run is reported, the others go on
                    traceback.print_exc()
                    r = {"error": f"{type(err).__name__}: {str(err).splitlines()[0][:160] if str(err) else ''}"}
                results.append(dict(task=env_id, obs=obs_mode, num_envs=B, **r))
                print(_row(env_id, obs_mode, B, r), flush=True)
    text = f"Taichi {arch}, ManiSkill {args.backend}, {gpu}\n\n{HEADER}\n" + "\n".join(
        _row(r["task"], r["obs"], r["num_envs"], r) for r in results)
    print("\n" + text)
    write_report(args.out, "scale.md", text)
    write_json(args.out, "scale.json", results, indent=1)
    return 0
