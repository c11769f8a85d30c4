"""``python -m gausstac_maniskill.bench touch [--tasks press slide] [--demos 100] [--eval-seeds 50]
[--train-seeds 3] [--epochs 300] [--mpm-dx 2e-3] [--procs 2] [--out out/touch] [--plot docs/touch_study.png]``
— does touch help? The same behaviour-cloning MLP trained with and without the tactile maps.

Per task: the scripted expert's successful episodes are recorded with :func:`gausstac_maniskill.collect.collect`
(obs mode ``state_dict``, no camera; reused from ``<out>/demos`` when a recording with the same settings and
enough episodes is there, ``--recollect`` records again), read with ``load_demos(path, rgb=False, pool=...)``,
and one per-step MLP (state -> normalized ``pd_joint_delta_pos`` action, MSE) is trained per variant and seed.
The variants take columns of the same ``state`` rows, with the same architecture, data, seed, epochs and
normalisation:

* ``touch``: proprioception (``obs/agent``: qpos, qvel, palm pose, fingertip poses) + the task's target
  (``obs/extra`` minus the contact-derived keys of :data:`CONTACT_KEYS`) + the tactile vector;
* ``no_touch``: the same without the tactile vector (the headline comparison: the two differ by it alone);
* ``full`` / ``full_no_tactile`` (tasks with contact-derived extra keys only, e.g. SlideCube's ``slid``, the
  distance slid *since the force first passed 0.1 N*): the whole recorded state with and without the tactile
  vector, to show what such a privileged key does.

Each policy is evaluated on ``--eval-seeds`` fresh seeds (from ``--eval-seed0``, disjoint from the recorded ones)
of the live env made with the recording's task kwargs (``recorded_env_kwargs``) and wrapped in
``TactileObsWrapper(flatten=True)``; the live vector is first checked against ``load_demos``' on a replayed demo.
An episode succeeds if the task reports success before its time limit (the task terminates on success or on a
failure). Prints the table, writes ``<out>/touch.json``, ``<out>/touch.txt`` and the bar plot ``--plot``
(success per task and variant, 95 % Wilson intervals over all evaluation episodes of all training seeds).
"""
from __future__ import annotations

import json
import math
import time
import warnings
from pathlib import Path

import numpy as np

from .common import cli, progress_bar, write_json, write_report

TASKS = {"press": "GaussTac-PressCube-v1", "slide": "GaussTac-SlideCube-v1"}
#: ``obs/extra`` keys that are read from the contact (the pad's force), not a task target: they are left
#: out of the ``touch`` and ``no_touch`` variants. PressCube's extra is its target force alone (the measured
#: force is not observed); SlideCube's ``slid`` is 0 until the index force first exceeds 0.1 N.
CONTACT_KEYS = {"GaussTac-PressCube-v1": (), "GaussTac-SlideCube-v1": ("slid",)}
VARIANTS = ("touch", "no_touch", "full", "full_no_tactile")


def env_id_of(task: str) -> str:
    return TASKS.get(task, task)


# ---------------------------------------------------------------------------- statistics
def wilson(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """95 % Wilson score interval of ``k`` successes in ``n`` trials."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return (0.0 if k == 0 else max(0.0, c - h), 1.0 if k == n else min(1.0, c + h))


# ---------------------------------------------------------------------------- data
def demo_path(out: str, env_id: str) -> Path:
    return Path(out) / "demos" / env_id / "trajectory.state_dict.pd_joint_delta_pos.physx_cpu.h5"


def collect_demos(env_id: str, num: int, mpm_dx: float, procs: int, out: str, seed: int = 0,
                  recollect: bool = False, progress: bool = True) -> tuple[Path, dict]:
    """Record ``num`` successful expert episodes (``state_dict``) unless a recording of ``env_id`` with the
    same ``mpm_dx`` and seed and at least ``num`` episodes is there; returns (path, collection summary)."""
    from ..collect import CollectConfig, collect

    path = demo_path(out, env_id)
    summary_path = path.parent / "collect_summary.json"
    if path.exists() and summary_path.exists() and not recollect:
        s = json.loads(summary_path.read_text())
        if s.get("episodes", 0) >= num and s.get("mpm_dx") == mpm_dx and s.get("seed") == seed:
            return path, {**s, "reused": True}
    cfg = CollectConfig(env_id=env_id, num_episodes=num, num_procs=procs, obs_mode="state_dict",
                        control_mode="pd_joint_delta_pos", seed=seed, out=str(Path(out) / "demos"),
                        only_success=True, mpm_dx=mpm_dx, progress=progress, overwrite=True)
    s = collect(cfg)
    s.update(mpm_dx=mpm_dx, seed=seed, only_success=True, obs_mode="state_dict")
    summary_path.write_text(json.dumps(s, indent=1))
    return path, {**s, "reused": False}


def state_columns(path, pool: int) -> dict:
    """``{"agent/<k>" | "extra/<k>" | "tactile": (start, stop)}``: where each observation key lies in
    ``load_demos``' ``state`` rows (the order it flattens them in, read from the file)."""
    import h5py
    from mani_skill.trajectory.dataset import load_h5_data

    from ..obs_wrappers import TactileLayout

    cols, at = {}, 0
    with h5py.File(path, "r") as f:
        obs = f["traj_0"]["obs"]
        for group in ("agent", "extra"):
            if group not in obs:
                continue
            for k, v in load_h5_data(obs[group]).items():
                if isinstance(v, dict):
                    raise ValueError(f"nested obs/{group}/{k} is not supported here")
                w = int(np.prod(np.asarray(v).shape[1:]))
                cols[f"{group}/{k}"] = (at, at + w)
                at += w
        n_pads = len(obs["tactile"])
    cols["tactile"] = (at, at + TactileLayout(pool=pool).size(n_pads))
    return cols


def variants_of(env_id: str) -> tuple[str, ...]:
    return VARIANTS if CONTACT_KEYS.get(env_id) else VARIANTS[:2]


def variant_keys(env_id: str, cols: dict, variant: str) -> list[str]:
    """The observation keys (in ``cols``' order) a variant's policy reads."""
    contact = {f"extra/{k}" for k in CONTACT_KEYS.get(env_id, ())}
    keys = [k for k in cols if k != "tactile"]
    if variant in ("touch", "no_touch"):
        keys = [k for k in keys if k not in contact]
    elif variant not in ("full", "full_no_tactile"):
        raise ValueError(f"unknown variant {variant!r}; choose among {VARIANTS}")
    if variant in ("touch", "full"):
        keys.append("tactile")
    return keys


def variant_index(cols: dict, keys: list[str]) -> np.ndarray:
    return np.concatenate([np.arange(*cols[k]) for k in keys]).astype(np.int64)


# ---------------------------------------------------------------------------- policy
def make_policy(in_dim: int, out_dim: int, hidden=(256, 256)):
    import torch
    from torch import nn

    class BCPolicy(nn.Module):
        """MLP on the standardised state, predicting the standardised action; ``forward`` returns the
        action, clipped to the controller's normalized range [-1, 1]."""

        def __init__(self):
            super().__init__()
            for name, d in (("x_mean", in_dim), ("x_std", in_dim), ("y_mean", out_dim), ("y_std", out_dim)):
                self.register_buffer(name, torch.zeros(d) if "mean" in name else torch.ones(d))
            layers, d = [], in_dim
            for h in hidden:
                layers += [nn.Linear(d, h), nn.ReLU()]
                d = h
            layers.append(nn.Linear(d, out_dim))
            self.net = nn.Sequential(*layers)

        def normalised(self, x):
            return self.net((x - self.x_mean) / self.x_std)

        def forward(self, x):
            return (self.normalised(x) * self.y_std + self.y_mean).clamp(-1.0, 1.0)

    return BCPolicy()


def train_bc(X: np.ndarray, Y: np.ndarray, seed: int, epochs: int, hidden=(256, 256), lr: float = 1e-3,
             batch: int = 64, std_floor: float = 1e-3, progress: bool = True, desc: str = "train"):
    """Behaviour cloning: MSE between the policy's and the expert's standardised action. Inputs and
    actions are standardised with the training rows' mean and std, each std floored at ``std_floor``
    (units: rad, rad/s, m, mm, N): many entries barely move in the demos (the other fingers, the palm;
    std 1e-7 to 1e-5) and would otherwise turn the live env's last-bit differences into large inputs.
    Returns (policy, seconds, final epoch loss)."""
    import torch

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    Xt, Yt = torch.as_tensor(X, dtype=torch.float32), torch.as_tensor(Y, dtype=torch.float32)
    pol = make_policy(X.shape[1], Y.shape[1], hidden)
    pol.x_mean.copy_(Xt.mean(0))
    pol.x_std.copy_(Xt.std(0).clamp(min=std_floor))
    pol.y_mean.copy_(Yt.mean(0))
    pol.y_std.copy_(Yt.std(0).clamp(min=std_floor))
    Yn = (Yt - pol.y_mean) / pol.y_std
    opt = torch.optim.Adam(pol.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(1, epochs))
    t0 = time.perf_counter()
    bar = progress_bar(epochs, desc, progress)
    loss_epoch = float("nan")
    for _ in range(epochs):
        perm = torch.as_tensor(rng.permutation(len(Xt)))
        tot = 0.0
        for i in range(0, len(Xt), batch):
            b = perm[i:i + batch]
            loss = ((pol.normalised(Xt[b]) - Yn[b]) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            tot += float(loss) * len(b)
        sched.step()
        loss_epoch = tot / len(Xt)
        bar.update(1)
    bar.close()
    pol.eval()
    return pol, time.perf_counter() - t0, loss_epoch


# ---------------------------------------------------------------------------- live env
def make_eval_env(env_id: str, path, pool: int):
    import gymnasium as gym

    import gausstac_maniskill  # noqa: F401 - registers the tasks
    from ..obs_wrappers import TactileObsWrapper, recorded_env_kwargs

    kw = recorded_env_kwargs(str(path))
    env = gym.make(env_id, obs_mode="state_dict", control_mode="pd_joint_delta_pos", sim_backend="physx_cpu", **kw)
    return TactileObsWrapper(env, flatten=True, pool=pool), kw


def check_live_vector(env, path, data: dict) -> dict:
    """Replay demo 0's actions from its seed on the wrapped live env; compare every step's flat
    observation with ``load_demos``' ``state`` rows of that demo. Returns the largest difference."""
    import torch

    meta = json.loads(Path(path).with_suffix(".json").read_text())
    seed = meta["episodes"][0]["episode_seed"]
    rows = data["state"][data["episode"] == 0]
    acts = data["actions"][data["episode"] == 0]
    obs, _ = env.reset(seed=seed)
    live = [obs.cpu().numpy()[0]]
    for a in acts[:-1]:
        obs, *_ = env.step(torch.as_tensor(a[None]))
        live.append(obs.cpu().numpy()[0])
    live = np.stack(live)
    if live.shape != rows.shape:
        return {"steps": len(rows), "shape_live": list(live.shape), "shape_demo": list(rows.shape), "equal": False,
                "max_abs_diff": float("inf")}
    diff = float(np.abs(live - rows).max())
    return {"seed": seed, "steps": len(rows), "dim": int(rows.shape[1]), "max_abs_diff": diff,
            "bit_equal": bool(np.array_equal(live, rows)), "equal": diff <= 1e-5}


def run_episode(env, policy, index, seed: int) -> dict:
    """One episode from ``seed``; ``policy`` None runs the task's scripted expert."""
    import torch

    obs, _ = env.reset(seed=seed)
    expert = None
    if policy is None:
        from ..experts import make_expert

        expert = make_expert(env)
        expert.reset()
    steps = 0
    while True:
        with torch.no_grad():
            a = expert.act(obs) if expert is not None else policy(obs[:, index].float())
        obs, _, term, trunc, info = env.step(a)
        steps += 1
        if bool(torch.as_tensor(term).any()) or bool(torch.as_tensor(trunc).any()):
            break
    return {"success": bool(torch.as_tensor(info["success"]).any()), "steps": steps,
            "force": float(torch.as_tensor(info["force"]).reshape(-1)[0])}


def evaluate(env, policy, index, seeds, progress: bool = True, desc: str = "eval") -> dict:
    t0 = time.perf_counter()
    bar = progress_bar(len(seeds), desc, progress)
    eps = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a policy that presses far in makes the linear pad warn every step
        for s in seeds:
            eps.append(run_episode(env, policy, index, s))
            bar.update(1)
    bar.close()
    k = sum(e["success"] for e in eps)
    return {"successes": k, "episodes": len(eps), "rate": k / max(1, len(eps)),
            "mean_steps": float(np.mean([e["steps"] for e in eps])), "eval_s": time.perf_counter() - t0,
            "success_per_seed": [int(e["success"]) for e in eps]}


# ---------------------------------------------------------------------------- study
def run_task(env_id: str, args, log=print) -> dict:
    import torch

    from ..obs_wrappers import load_demos

    t0 = time.perf_counter()
    path, csum = collect_demos(env_id, args.demos, args.mpm_dx, args.procs, args.out, seed=args.seed,
                               recollect=args.recollect, progress=args.progress)
    log(f"{env_id}: demos {path} ({csum['episodes']} episodes, {csum['attempted']} tried, " +
        ("reused" if csum["reused"] else "collected in %.1f s" % csum["wall_seconds"]) + ")")
    data = load_demos(str(path), num_traj=args.demos, rgb=False, pool=args.pool)
    cols = state_columns(path, args.pool)
    D = cols["tactile"][1] - cols["tactile"][0]
    assert data["state"].shape[1] == cols["tactile"][1], (data["state"].shape, cols)
    assert np.array_equal(data["state"][:, cols["tactile"][0]:], data["tactile"])
    meta = json.loads(path.with_suffix(".json").read_text())
    train_seeds = sorted({int(e["episode_seed"]) for e in meta["episodes"][:args.demos]})
    eval_seeds = list(range(args.eval_seed0, args.eval_seed0 + args.eval_seeds))
    overlap = sorted(set(train_seeds) & set(eval_seeds))
    if overlap:
        raise ValueError(f"evaluation seeds {overlap[:5]}... were recorded as demos; pick another --eval-seed0")

    env, kw = make_eval_env(env_id, path, args.pool)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            check = check_live_vector(env, path, data)
        log(f"  live vector against load_demos (demo 0, {check['steps']} steps): max |diff| "
            f"{check['max_abs_diff']:.3g}{' (bit-equal)' if check.get('bit_equal') else ''}")
        if not check["equal"]:
            raise AssertionError(f"live observation differs from the recorded state: {check}")
        result = {"env_id": env_id, "demo_path": str(path), "env_kwargs": kw, "collect": csum,
                  "demos": int(data["episode"].max() + 1), "steps": int(len(data["state"])),
                  "train_episode_seeds": [train_seeds[0], train_seeds[-1]], "eval_seeds": [eval_seeds[0],
                                                                                           eval_seeds[-1]],
                  "state_columns": {k: list(v) for k, v in cols.items()}, "tactile_dim": D,
                  "contact_keys_removed": list(CONTACT_KEYS.get(env_id, ())), "live_check": check,
                  "variants": {}}
        if args.expert:
            result["expert"] = evaluate(env, None, None, eval_seeds, args.progress, f"{env_id} expert")
            e = result["expert"]
            log(f"  expert on the eval seeds: {e['successes']}/{e['episodes']}")
        for v in variants_of(env_id):
            keys = variant_keys(env_id, cols, v)
            idx = variant_index(cols, keys)
            X, Y = data["state"][:, idx], data["actions"]
            runs = []
            for s in range(args.train_seeds):
                pol, t_train, loss = train_bc(X, Y, seed=s, epochs=args.epochs, hidden=tuple(args.hidden),
                                              lr=args.lr, batch=args.batch, std_floor=args.std_floor,
                                              progress=args.progress,
                                              desc=f"{env_id} {v} seed {s} train")
                ev = evaluate(env, pol, torch.as_tensor(idx), eval_seeds, args.progress,
                              f"{env_id} {v} seed {s} eval")
                runs.append({"seed": s, "train_s": t_train, "final_loss": loss, **ev})
                log(f"  {v:16s} seed {s}: {ev['successes']}/{ev['episodes']} (train {t_train:.1f} s, loss "
                    f"{loss:.4f}, eval {ev['eval_s']:.1f} s)")
            k = sum(r["successes"] for r in runs)
            n = sum(r["episodes"] for r in runs)
            lo, hi = wilson(k, n)
            result["variants"][v] = {
                "keys": keys, "dim": int(len(idx)), "successes": k, "episodes": n, "rate": k / max(1, n),
                "wilson95": [lo, hi], "rate_per_seed": [r["rate"] for r in runs],
                "train_s": float(np.mean([r["train_s"] for r in runs])),
                "eval_s": float(np.mean([r["eval_s"] for r in runs])), "runs": runs}
    finally:
        env.close()
    result["wall_s"] = time.perf_counter() - t0
    return result


def table(results: dict) -> str:
    lines = ["| task | variant | obs dim | success | 95 % Wilson | per training seed | demos (steps) | train s | "
             "eval s |", "|---|---|---|---|---|---|---|---|---|"]
    for env_id, r in results["tasks"].items():
        name = env_id.replace("GaussTac-", "").replace("-v1", "")
        if "expert" in r:
            e = r["expert"]
            lo, hi = wilson(e["successes"], e["episodes"])
            lines.append(f"| {name} | expert | – | {e['successes']}/{e['episodes']} = {e['rate']:.0%} | "
                         f"{lo:.2f}–{hi:.2f} | – | – | – | {e['eval_s']:.0f} |")
        for v, s in r["variants"].items():
            per = ", ".join(f"{p:.0%}" for p in s["rate_per_seed"])
            lines.append(f"| {name} | {v} | {s['dim']} | {s['successes']}/{s['episodes']} = {s['rate']:.0%} | "
                         f"{s['wilson95'][0]:.2f}–{s['wilson95'][1]:.2f} | {per} | {r['demos']} ({r['steps']}) | "
                         f"{s['train_s']:.1f} | {s['eval_s']:.0f} |")
    return "\n".join(lines)


def plot(results: dict, path: str) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = list(results["tasks"])
    colors = {"expert": "0.6", "touch": "tab:blue", "no_touch": "tab:orange", "full": "tab:green",
              "full_no_tactile": "tab:red"}
    labels = {"expert": "scripted expert", "touch": "BC with touch", "no_touch": "BC without touch",
              "full": "BC, full state (+ contact key)", "full_no_tactile": "BC, full state − tactile"}
    fig, ax = plt.subplots(figsize=(1.8 + 2.6 * len(tasks), 3.6))
    width, seen = 0.16, set()
    for i, env_id in enumerate(tasks):
        r = results["tasks"][env_id]
        bars = ([("expert", r["expert"]["successes"], r["expert"]["episodes"])] if "expert" in r else []) + \
            [(v, s["successes"], s["episodes"]) for v, s in r["variants"].items()]
        x0 = i - width * (len(bars) - 1) / 2
        for j, (v, k, n) in enumerate(bars):
            p = k / max(1, n)
            lo, hi = wilson(k, n)
            ax.bar(x0 + j * width, p, width * 0.92, color=colors[v], label=None if v in seen else labels[v],
                   yerr=[[max(0.0, p - lo)], [max(0.0, hi - p)]], capsize=3)
            seen.add(v)
    ax.set_xticks(range(len(tasks)))
    ax.set_xticklabels([t.replace("GaussTac-", "").replace("-v1", "") for t in tasks])
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("success rate")
    c = results["config"]
    ax.set_title(f"Does touch help? BC-MLP, {c['demos']} demos, {c['train_seeds']} seeds × {c['eval_seeds']} "
                 "eval episodes (95 % Wilson)", fontsize=8)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def main(argv: list[str]) -> int:
    ap = cli("touch", __doc__)
    ap.add_argument("--tasks", nargs="+", default=["press", "slide"],
                    help="press, slide (or full env ids); default both")
    ap.add_argument("--demos", type=int, default=100, help="successful expert episodes per task (default 100)")
    ap.add_argument("--eval-seeds", type=int, default=50, help="evaluation episodes per policy (default 50)")
    ap.add_argument("--eval-seed0", type=int, default=100000, help="first evaluation seed (default 100000)")
    ap.add_argument("--train-seeds", type=int, default=3, help="training seeds per variant (default 3)")
    ap.add_argument("--epochs", type=int, default=300)
    ap.add_argument("--hidden", type=int, nargs="+", default=[256, 256])
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--std-floor", type=float, default=1e-3, help="floor of the standardisation's std (default 1e-3)")
    ap.add_argument("--pool", type=int, default=4, help="tactile pooling (default 4: 256 values for 4 pads)")
    ap.add_argument("--mpm-dx", type=float, default=2e-3, help="grid spacing of the recording (default 2e-3)")
    ap.add_argument("--procs", type=int, default=2, help="collection worker processes (default 2)")
    ap.add_argument("--seed", type=int, default=0, help="first collection seed (default 0)")
    ap.add_argument("--recollect", action="store_true", help="record the demos again even if they are there")
    ap.add_argument("--no-expert", dest="expert", action="store_false", help="skip the expert on the eval seeds")
    ap.add_argument("--out", default="out/touch")
    ap.add_argument("--plot", default="docs/touch_study.png", help="bar plot path ('' for none)")
    ap.add_argument("--no-progress", dest="progress", action="store_false")
    args = ap.parse_args(argv)

    import torch

    torch.set_num_threads(1)
    t0 = time.perf_counter()
    results = {"config": {k: v for k, v in vars(args).items()}, "tasks": {}}
    for task in args.tasks:
        env_id = env_id_of(task)
        results["tasks"][env_id] = run_task(env_id, args)
        write_json(args.out, "touch.json", results, indent=1)  # partial results survive a later failure
    results["wall_s"] = time.perf_counter() - t0
    text = table(results)
    print(text)
    write_json(args.out, "touch.json", results, indent=1)
    write_report(args.out, "touch.txt", text)
    if args.plot:
        print("plot:", plot(results, args.plot))
    return 0
