"""``python -m gausstac_maniskill.bench resolution [--tasks ID ...] [--dx 2e-3 1e-3] [--settle 10]`` — do
the tasks hold across MPM grids?

Per task and grid spacing, one episode with the same seed: the scripted expert until success
(``--settle`` more steps), and the actions it took at the first ``--dx`` replayed open loop at
each finer grid (the same press: what differs is the MPM's answer). Prints each run's task
measures at the last step (pad forces [N], apex depth [mm] or compression) and the wall time
per control step split into physics / MPM / tactile / render [ms].
"""
from __future__ import annotations

from .common import cli, run_expert_episode, split_cells, step_split_ms, write_report

TASKS = ["GaussTac-PressCube-v1", "GaussTac-GraspSqueezeSponge-v1"]


def _press(u, info) -> dict:
    return {"force [N]": float(info["force"][0]), "apex depth [mm]": 1e3 * float(u.apex_in_face()[0, 2])}


def _squeeze(u, info) -> dict:
    return {"compression": float(info["compression"][0]), "pad force [N]": float(info["pad_force"][0])}


def _pinch(u, info) -> dict:
    out = {"thumb [N]": float(u.touch_force("thumb")[0]), "index [N]": float(u.touch_force("index")[0])}
    if "compression" in info:
        out = {"compression": float(info["compression"][0]), **out}
    return out


#: what each task's resolution check reads at the end of a run
MEASURES = {
    "GaussTac-PressCube-v1": _press,
    "GaussTac-SlideCube-v1": _press,
    "GaussTac-SqueezeSponge-v1": _squeeze,
    "GaussTac-GraspLiftCube-v1": _pinch,
    "GaussTac-GraspSqueezeSponge-v1": _pinch,
}


def run_task(env_id: str, dxs, seed: int = 0, settle: int = 10, control_mode: str = "pd_joint_pos",
             **env_kwargs) -> list[dict]:
    """The expert at every grid spacing in ``dxs`` [m] and the first grid's actions replayed
    at the others.

    Returns:
        One dict per run: ``dx`` [m], ``run`` (``"expert"`` or ``"replay"``), ``steps``,
        ``success_at`` (first successful control step, None: never), ``measures`` (the
        task's :data:`MEASURES` at the last step) and ``split`` (:func:`step_split_ms`
        from the second step on).
    """
    import gymnasium as gym

    import gausstac_maniskill.tasks  # noqa: F401  (registers the tasks with ManiSkill)

    rows, actions = [], None
    for run in ("expert", "replay"):
        for i, dx in enumerate(dxs):
            if run == "replay" and i == 0:
                continue
            env = gym.make(env_id, sim_backend="physx_cpu", obs_mode="state", control_mode=control_mode,
                           mpm_dx=dx, **env_kwargs)
            try:
                taken = []
                _, info, done, timing, _ = run_expert_episode(
                    env, seed, f"{env_id} {run} dx {dx * 1e3:g} mm", lambda info, a: taken.append(a),
                    settle=settle, replay=actions if run == "replay" else None)
                rows.append(dict(dx=dx, run=run, steps=len(timing), success_at=done,
                                 measures=MEASURES[env_id](env.unwrapped, info),
                                 split=step_split_ms(timing[1:])))  # the first step compiles
            finally:
                env.close()
            if run == "expert" and i == 0:
                actions = taken
    return rows


def table(env_id: str, rows: list[dict]) -> str:
    """Markdown table of :func:`run_task`'s rows; each measure with its relative difference
    from the first grid's expert run."""
    names = list(rows[0]["measures"])
    ref = rows[0]["measures"]
    head = (f"| {env_id} | dx [mm] | steps | success at step | "
            + " | ".join(names) + " | ms/step: physics | mpm | tactile | render | total |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        cells = [f"{v:.3f}" if r is rows[0] else f"{v:.3f} ({100 * (v - ref[k]) / abs(ref[k]):+.1f} %)"
                 for k, v in r["measures"].items()]
        lines.append(f"| {r['run']} | {r['dx'] * 1e3:g} | {r['steps']} | "
                     f"{'-' if r['success_at'] is None else r['success_at']} | " + " | ".join(cells)
                     + f" | {split_cells(r['split'])} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = cli("resolution", __doc__)
    ap.add_argument("--tasks", nargs="+", default=TASKS, choices=sorted(MEASURES), metavar="ENV_ID")
    ap.add_argument("--dx", type=float, nargs="+", default=[2e-3, 1e-3],
                    help="MPM grid spacings [m]; the first one's expert actions are replayed at the others")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--settle", type=int, default=10, help="expert steps after the first success")
    ap.add_argument("--out", default="out/bench_resolution", help="folder for the report")
    args = ap.parse_args(argv)
    if len(args.dx) < 2:
        ap.error("--dx needs at least two grid spacings")
    text = "\n\n".join(table(t, run_task(t, args.dx, args.seed, args.settle)) for t in args.tasks)
    text = (f"Same seed ({args.seed}) at each grid; pd_joint_pos, physx_cpu, obs_mode state. "
            f"Differences against the {args.dx[0] * 1e3:g} mm expert run.\n\n{text}")
    print(text)
    write_report(args.out, "resolution.md", text)
    return 0
