"""ManiSkill env benchmark: step time of every GaussTac task split into physics / MPM / tactile /
render, reset time, and the task outcome, against SAPIEN's own camera and ManiSkill's FSR-tactile
Allegro task.

``python -m gausstac_maniskill.bench envs [--steps N] [--settle N] [--dx 2e-3 1.5e-3] [--tasks ID ...]
[--pad-solvers auto mpm fem] [--sweep-tasks ID ...] [--no-fsr] [--out DIR]``

Each task's scripted expert runs a whole episode (until success and ``--settle`` more steps) with
the splat camera (128×128 ``rgb``, dx = 2 mm, the tasks' default pads); the ``--sweep-tasks`` also
at the finer ``--dx`` with each of ``--pad-solvers`` (the outcome column then the force error);
each task also with ``camera="sapien"``, stepped in turn with the splat run; and ManiSkill's
``RotateSingleObjectInHandLevel0-v1`` with FSR tactile. Times are means over the timed steps
[ms], the first (compiling) step not counted; writes ``envs.json``.
"""
from __future__ import annotations

import os
import platform
import time

import numpy as np

from .common import cli, write_json

TASKS = ["GaussTac-Gesture-v1", "GaussTac-PressCube-v1", "GaussTac-SlideCube-v1", "GaussTac-SqueezeSponge-v1",
         "GaussTac-GraspLiftCube-v1", "GaussTac-GraspSqueezeSponge-v1"]
PARTS = ("physics", "mpm", "tactile", "render")


def _outcome(env_id, info) -> str:
    if env_id == "GaussTac-PressCube-v1":
        return f"success={bool(info['success'][0])}, |F-F*|={float(info['force_error'][0]):.3f} N"
    if env_id == "GaussTac-SlideCube-v1":
        return f"success={bool(info['success'][0])}, slid={1e3 * float(info['slid'][0]):.1f} mm"
    if env_id in ("GaussTac-SqueezeSponge-v1", "GaussTac-GraspSqueezeSponge-v1"):
        return f"success={bool(info['success'][0])}, |c-c*|={float(info['compression_error'][0]):.3f}"
    if env_id == "GaussTac-GraspLiftCube-v1":
        return (f"success={bool(info['success'][0])}, height={1e3 * float(info['height'][0]):.1f} mm, "
                f"held {float(info['hold_time'][0]):.2f} s")
    if "success" in info:
        return f"success={bool(info['success'][0])}"
    return "-"


class _Run:
    """One GaussTac env driven by its scripted expert, with the step timings it recorded."""

    def __init__(self, env_id: str, camera: str = "splat", dx: float = 2e-3, resets: int = 3,
                 steps: int | None = None, settle: int = 5, pad_solver: str = "auto"):
        import gymnasium as gym
        from mani_skill.utils.registration import REGISTERED_ENVS

        from ..experts import make_expert

        self.env_id = env_id
        self.env = gym.make(env_id, obs_mode="rgb", sim_backend="physx_cpu", control_mode="pd_joint_pos",
                            camera=camera, mpm_dx=dx, splat_size=(128, 128), pad_solver=pad_solver)
        self.base = self.env.unwrapped
        reset_s = []
        for k in range(resets):
            t0 = time.perf_counter()
            self.env.reset(seed=k)
            reset_s.append(time.perf_counter() - t0)
        self.reset_ms = 1e3 * float(np.mean(reset_s[1:] or reset_s))
        self.obs, _ = self.env.reset(seed=0)
        self.expert = make_expert(self.env)
        self.expert.reset()
        self.cam = self.base._sensors.get("splat_camera")
        self.rows, self.info, self.particles, self.k, self.pictures = [], {}, 0, 0, None
        limit = REGISTERED_ENVS[env_id].max_episode_steps
        self.max_steps = limit if steps is None else min(steps + 1, limit)
        self.settle, self.success_at = settle, None

    @property
    def finished(self) -> bool:
        """The episode is over: success and ``settle`` steps after it, or the step budget."""
        return self.k >= self.max_steps or (self.success_at is not None and self.k > self.success_at + self.settle)

    def step(self) -> None:
        """One control step; from the second on (the first compiles Taichi kernels) it is timed."""
        if self.finished:
            return
        if self.k == 1 and hasattr(self.cam, "background_renders"):
            self.pictures = self.cam.background_renders
        self.obs, _, _, _, self.info = self.env.step(self.expert.act(self.obs))
        self.particles = max(self.particles, sum(g.count for g in self.base.mpm_world.groups if g.awake))
        if self.k > 0:
            self.rows.append({p: self.base.step_timing[p] for p in PARTS + ("total",)})
        if self.success_at is None and "success" in self.info and bool(self.info["success"][0]):
            self.success_at = self.k
        self.k += 1

    def close(self) -> dict:
        """Close the env; means of the timed steps (ms), the median render time, the outcome."""
        pictures = None if self.pictures is None else self.cam.background_renders - self.pictures
        self.env.close()
        out = {p: 1e3 * float(np.mean([r[p] for r in self.rows])) for p in PARTS + ("total",)}
        out.update(reset=self.reset_ms, outcome=_outcome(self.env_id, self.info), particles=self.particles,
                   bg_pictures=pictures, render_median=1e3 * float(np.median([r["render"] for r in self.rows])),
                   steps=len(self.rows))
        return out


def run_gausstac(env_id: str, steps: int | None = None, camera: str = "splat", dx: float = 2e-3,
                 resets: int = 3, settle: int = 5, pad_solver: str = "auto") -> dict:
    """One expert episode of ``env_id`` (see the module docstring); its timings and outcome."""
    run = _Run(env_id, camera, dx, resets, steps, settle, pad_solver)
    while not run.finished:
        run.step()
    return run.close()


def run_side_by_side(env_id: str, steps: int | None = None, dx: float = 2e-3, settle: int = 5) -> tuple[dict, dict]:
    """The task with the splat camera and with SAPIEN's camera in one process, stepped in
    turn (which one goes first alternates), so that both see the same machine load; returns
    (splat, sapien) results as :func:`run_gausstac`."""
    runs = {"splat": _Run(env_id, "splat", dx, steps=steps, settle=settle),
            "sapien": _Run(env_id, "sapien", dx, steps=steps, settle=settle)}
    k = 0
    while not all(r.finished for r in runs.values()):
        for cam in (("splat", "sapien") if k % 2 else ("sapien", "splat")):
            runs[cam].step()
        k += 1
    return runs["splat"].close(), runs["sapien"].close()


def run_fsr(steps: int = 15) -> dict:
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401

    env = gym.make("RotateSingleObjectInHandLevel0-v1", obs_mode="rgb", sim_backend="physx_cpu",
                   sensor_configs=dict(width=128, height=128))
    reset_s = []
    for k in range(3):
        t0 = time.perf_counter()
        env.reset(seed=k)
        reset_s.append(time.perf_counter() - t0)
    times, render = [], []
    base = env.unwrapped
    orig = base._get_obs_sensor_data

    def timed(*a, **kw):
        t0 = time.perf_counter()
        r = orig(*a, **kw)
        render.append(time.perf_counter() - t0)
        return r

    base._get_obs_sensor_data = timed
    for k in range(steps + 1):
        t0 = time.perf_counter()
        env.step(env.action_space.sample() * 0.2)
        if k > 0:
            times.append(time.perf_counter() - t0)
    env.close()
    total, rend = 1e3 * float(np.mean(times)), 1e3 * float(np.mean(render[1:]))
    return dict(physics=total - rend, mpm=0.0, tactile=0.0, render=rend, total=total,
                reset=1e3 * float(np.mean(reset_s[1:])), outcome="FSR impulses (16 links)", particles=0,
                bg_pictures=None, render_median=1e3 * float(np.median(render[1:])), steps=steps)


def main(argv=None) -> int:
    ap = cli("envs", __doc__)
    ap.add_argument("--steps", type=int, default=None,
                    help="at most this many timed control steps per run (default: the whole expert episode; "
                         "the FSR row: 15)")
    ap.add_argument("--settle", type=int, default=5, help="expert steps after the first success")
    ap.add_argument("--dx", type=float, nargs="+", default=[2e-3, 1.5e-3],
                    help="MPM grid spacings [m] for the PressCube resolution sweep")
    ap.add_argument("--out", default="out/bench", help="folder for envs.json")
    ap.add_argument("--tasks", nargs="+", default=TASKS, choices=TASKS, metavar="ENV_ID",
                    help=f"GaussTac tasks to run (default: all of {', '.join(TASKS)})")
    ap.add_argument("--pad-solvers", nargs="+", default=["auto"], choices=["auto", "mpm", "fem"],
                    help="the pads' solvers of the resolution sweep (GaussTacEnv's pad_solver; auto, the default: "
                         "the tasks' default, fem for rigid objects)")
    ap.add_argument("--sweep-tasks", nargs="+", default=["GaussTac-PressCube-v1"], choices=TASKS, metavar="ENV_ID",
                    help="tasks of the resolution sweep (default: PressCube)")
    ap.add_argument("--no-fsr", action="store_true", help="skip ManiSkill's FSR-tactile Allegro row")
    args = ap.parse_args(argv)
    from .. import backend, environment

    print(f"[bench envs] Taichi backend: {backend.init(environment.read('GAUSSTAC_ARCH'))}, "
          f"machine: {platform.machine()}, {os.cpu_count()} cores")
    runs = []
    for env_id in args.tasks:
        splat, sapien = run_side_by_side(env_id, args.steps, settle=args.settle)
        runs.append((env_id, "splat", 2e-3, splat))
        runs.append((env_id, "sapien", 2e-3, sapien))
    for env_id in args.sweep_tasks:
        for solver in args.pad_solvers:
            for dx in args.dx:
                if dx != 2e-3 or solver != "auto" or env_id not in args.tasks:  # (that one ran above)
                    run = run_gausstac(env_id, args.steps, "splat", dx, settle=args.settle, pad_solver=solver)
                    runs.append((f"{env_id} ({solver} pads)", "splat", dx, run))
    if not args.no_fsr:
        runs.append(("RotateSingleObjectInHandLevel0-v1 (allegro_hand_right_touch)", "sapien", None,
                     run_fsr(args.steps or 15)))
    print("\n| task | camera | MPM dx [mm] | active particles | timed steps | reset [ms] | step [ms] | physics | "
          "MPM | tactile | render | background pictures | outcome |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for env_id, cam, dx, r in runs:
        bg = "-" if r["bg_pictures"] is None else f"{r['bg_pictures']}/{r['steps']}"
        print(f"| {env_id} | {cam} | {'-' if dx is None else f'{1e3 * dx:g}'} | {r['particles']} | {r['steps']} | "
              f"{r['reset']:.0f} | {r['total']:.0f} | {r['physics']:.0f} | {r['mpm']:.0f} | {r['tactile']:.1f} | "
              f"{r['render']:.1f} | {bg} | {r['outcome']} |")
    print("\nCamera side by side (same process, steps in turn; median render time per step, ms: SAPIEN's "
          "scene update, the camera's picture and its observation)")
    print("\n| task | splat [ms] | SAPIEN [ms] | splat / SAPIEN |")
    print("|---|---|---|---|")
    for (env_id, _, _, a), (_, _, _, b) in zip(runs[0:2 * len(args.tasks):2], runs[1:2 * len(args.tasks):2]):
        print(f"| {env_id} | {a['render_median']:.2f} | {b['render_median']:.2f} | "
              f"{a['render_median'] / b['render_median']:.2f} |")
    write_json(args.out, "envs.json", [dict(env=e, camera=c, dx=d, **r) for e, c, d, r in runs], indent=1)
    return 0
