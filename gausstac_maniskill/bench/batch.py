"""``python -m gausstac_maniskill.bench batch [--envs 1 4 16] [--steps 6] [--dx 1e-3] [--camera W H]`` —
B envs in one MPM world against B worlds stepped in a loop.

Each env is the Allegro hand with a 6 mm ball pressed into its index pad (a different depth per
env), run as one :class:`~gausstac_maniskill.batch.BatchedCosim` and as B
:class:`~gausstac_maniskill.cosim.GaussTacSim` in turn. Prints per B the wall time per 20 ms
control step of both (and its host part), Taichi launches per step, the batch's largest map
difference from the same scene alone, and the cost of a pad falling asleep or waking up;
``--camera W H`` adds the batched splat render against one render per env. Taichi arch:
``GAUSSTAC_ARCH`` (cpu by default).
"""
from __future__ import annotations

import time

import numpy as np

from .common import cli

R = 6e-3
DT = 0.02


def _scenes(B: int, names, base, sensor):
    """Per env: link poses [L, 4, 4] and the ball's centre at step k."""
    from ..transforms import make_pose

    i = names.index("link_3.0_tip")
    out = []
    for b in range(B):
        M = make_pose([0.0015 * (b % 4), 0.001 * (b // 4 % 4), 0.0])
        P = M @ base
        W = P[i] @ sensor
        depth = 0.4e-3 + 0.5e-3 * (b % 6) / 5

        def centre(k, W=W, d=depth):
            return make_pose(W[:3, 3] + W[:3, 2] * (R + 0.5e-3 - (d + 0.5e-3) * min(1.0, (k + 1) / 4)))

        out.append((P, centre))
    return out


class _Launches:
    """Counts Taichi launches (kernels and the ndarray copies, which are kernels too) and the
    wall time spent in them, by wrapping Taichi's ``Kernel.__call__``. On the CPU a launch
    returns when its kernel is done; on CUDA it returns once queued, and ``seconds`` is only
    the launch's host side."""

    def __init__(self):
        from taichi.lang import kernel_impl

        self.n, self.seconds = 0, 0.0
        self._cls, self._orig = kernel_impl.Kernel, kernel_impl.Kernel.__call__

        def counted(kernel, *a, **kw):
            t0 = time.perf_counter()
            try:
                return self._orig(kernel, *a, **kw)
            finally:
                self.n += 1
                self.seconds += time.perf_counter() - t0

        self._cls.__call__ = counted

    def close(self):
        self._cls.__call__ = self._orig


def main(argv: list[str] | None = None) -> int:
    ap = cli("batch", __doc__)
    ap.add_argument("--envs", type=int, nargs="+", default=[1, 4, 16], help="env counts B (default: 1 4 16)")
    ap.add_argument("--steps", type=int, default=6, help="control steps of 20 ms per run (default: 6)")
    ap.add_argument("--dx", type=float, default=1e-3, help="grid spacing [m] (default: 1 mm, the product's)")
    ap.add_argument("--loop-max", type=int, default=64,
                    help="run the loop of single worlds only up to this B (default: 64); above it, only the batch")
    ap.add_argument("--camera", type=int, nargs=2, metavar=("W", "H"),
                    help="also time the splat camera, one W × H picture per env, batched against env by env")
    args = ap.parse_args(argv)
    from tqdm import tqdm

    from .. import backend
    from ..batch import BatchedCosim
    from ..config import PadSolverSettings, SolverSettings
    from ..cosim import GaussTacSim
    from ..geometry import Sphere
    from ..pose import MujocoPoseSource
    from ..tactile import allegro_pad_specs

    arch = backend.ensure_init()
    pads = allegro_pad_specs()
    names = [p.link for p in pads]
    base = MujocoPoseSource().link_poses(names)[0].double().numpy()
    settings = SolverSettings(dx=args.dx)
    sensor = GaussTacSim(pads, dict(zip(names, base)), settings=settings).pads["link_3.0_tip"].sensor_frame
    print(f"\nBatched co-simulator, Allegro index pad pressed by a 6 mm ball in every env, dx = {args.dx * 1e3:g} mm, "
          f"Taichi {arch}, {args.steps - 1} timed steps of {DT * 1e3:g} ms")
    print("| B | particles | substeps | batched [ms/step] | of it host | loop [ms/step] | of it host | loop / batched "
          "| batched per env [ms] | launches batched / loop | env 0 vs alone (max rel) | mean index force [N] "
          "| wake/sleep event [ms] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|", flush=True)
    cameras = []
    for B in tqdm(args.envs, desc="env counts", unit="B"):  # each row as it is measured: a cut run keeps them
        scenes = _scenes(B, names, base, sensor)
        poses = np.stack([P for P, _ in scenes])
        batch = BatchedCosim(pads, names, poses, settings=settings, pad_settings=PadSolverSettings(solver="mpm"))
        batch.add_rigid_object("ball", [Sphere(radius=R, pose=c(-1), friction=0.5) for _, c in scenes])
        loop = []
        for P, c in (scenes if B <= args.loop_max else scenes[:1]):
            sim = GaussTacSim(pads, dict(zip(names, P)), settings=settings,
                              pad_settings=PadSolverSettings(solver="mpm"))
            sim.add_rigid_object("ball", Sphere(radius=R, pose=c(-1), friction=0.5))
            loop.append(sim)
        t_batch = t_loop = h_batch = h_loop = 0.0
        n_batch = n_loop = 0
        for k in range(args.steps):
            counter = _Launches()
            t0 = time.perf_counter()
            maps = batch.step(poses, DT, {"ball": np.stack([c(k) for _, c in scenes])})
            t1 = time.perf_counter()
            nb, sb = counter.n, counter.seconds
            sub = batch.world.last_step.substeps
            for sim, (P, c) in zip(loop, scenes):  # zip: only env 0 above --loop-max
                sim.begin_step(dict(zip(names, P)), {"ball": c(k)})
                sim.world.step(DT, min_substeps=sub)
                sim.end_step()
                sim.tactile()
            t2 = time.perf_counter()
            counter.close()
            if k:  # the first step compiles
                t_batch += t1 - t0
                t_loop += t2 - t1
                h_batch += t1 - t0 - sb  # outside the launches: Python's share
                h_loop += t2 - t1 - (counter.seconds - sb)
                n_batch += nb
                n_loop += counter.n - nb
        alone = loop[0].tactile()
        err = max(float((maps[p][key][0] - alone[p][key]).abs().max()) / max(float(alone[p][key].abs().max()), 1e-30)
                  for p in batch.pad_names for key in ("depth", "shear", "force") if alone[p][key].abs().max() > 0)
        force = float(maps["link_3.0_tip"]["force"].sum(dim=(1, 2)).mean())
        event = _wake_sleep_ms(batch)
        n = args.steps - 1
        est = len(loop) < B  # the loop ran env 0 alone: B times its time and launches, an estimate
        scale = B if est else 1
        tqdm.write(_row(B, batch.world.last_step.active_particles, sub, (t_batch / n, h_batch / n),
                        (scale * t_loop / n, scale * h_loop / n), n_batch / n, scale * n_loop / n, err, force, est,
                        event))
        if args.camera:
            cameras.append(_camera_row(batch, *args.camera))
    if cameras:
        print(f"\nSplat camera, one {args.camera[0]} × {args.camera[1]} picture per env (posing included; "
              f"best of 3 after a first untimed one)")
        print("| B | Gaussians | batched [ms] | env by env [ms] | env by env / batched | launches batched / env by env "
              "| max abs difference |")
        print("|---|---|---|---|---|---|---|")
        print("\n".join(cameras))
    return 0


def _camera_row(batch, width: int, height: int) -> str:
    """Attach the hand's and the ball's Gaussians to every env and time one picture per env,
    batched and env by env (each scene's own render); returns the table row."""
    import torch

    from ..demo import load_hand_gaussians
    from ..pose import MujocoPoseSource
    from ..render import box_gaussians
    from ..splat import MANISKILL_DEFAULT, intrinsics_from_fov, look_at

    src = MujocoPoseSource()
    hand, links, closed = load_hand_gaussians()
    rest = dict(zip(src.link_names, src.link_poses()[0].double().numpy()))
    B = batch.num_envs
    for scene in batch.scenes:
        scene.attach_gaussians(hand, links, {"ball": box_gaussians((R, R, R), 1.5e-3)}, closed_links=closed)
        tip = scene._link_pose["link_3.0_tip"]
        move = tip @ np.linalg.inv(rest["link_3.0_tip"])  # the env's hand offset
        scene._link_pose.update({n: move @ T for n, T in rest.items() if n not in scene._link_pose})
    tips = [s._link_pose["link_3.0_tip"][:3, 3] for s in batch.scenes]
    V = torch.stack([look_at(t + np.array([0.05, -0.12, 0.08]), t) for t in tips])
    K = intrinsics_from_fov(width, height, 0.9)[None].expand(B, 3, 3)
    kw = dict(background=(1.0, 1.0, 1.0), lighting=MANISKILL_DEFAULT)

    def batched():
        return batch.render(V, K, width, height, **kw).rgb

    def one_by_one():
        return torch.cat([s.render(V[b:b + 1], K[b:b + 1], width, height, **kw).rgb
                          for b, s in enumerate(batch.scenes)])

    times, launches, pictures = {}, {}, {}
    for name, fn in (("batched", batched), ("loop", one_by_one)):
        best = float("inf")
        for k in range(4):
            for s in batch.scenes:
                s.end_step()  # a new step: posing is part of every picture
            counter = _Launches()
            t0 = time.perf_counter()
            pictures[name] = fn()
            dt = time.perf_counter() - t0
            counter.close()
            launches[name] = counter.n
            if k:
                best = min(best, dt)
        times[name] = best
    diff = float((pictures["batched"] - pictures["loop"]).abs().max())
    n = len(batch._splat._framed)
    return (f"| {B} | {n} | {times['batched'] * 1e3:.0f} | {times['loop'] * 1e3:.0f} | "
            f"{times['loop'] / times['batched']:.2f} | {launches['batched']} / {launches['loop']} | {diff:.1e} |")


def _wake_sleep_ms(batch) -> float:
    """Mean wall time [ms] of env 0's index pad falling asleep or waking up, the device
    arrays brought up to date (what the next step would find); the first pair is not
    timed (its kernels compile)."""
    world, group = batch.world, batch.scenes[0].pad_slots()[batch.pad_names.index("link_3.0_tip")][0]
    times = []
    for k in range(4):
        t0 = time.perf_counter()
        world.set_awake(group, not world.group(group).awake)
        world.device_state(("x",))
        times.append(time.perf_counter() - t0)
    return float(np.mean(times[2:])) * 1e3


def _row(B, npart, sub, batched, loop, nb, nl, err, f, est, event) -> str:
    """A table row; ``batched`` and ``loop`` are (wall, outside launches) [s] per step."""
    mark = " (B × env 0 alone)" if est else ""
    (tb, hb), (tl, hl) = batched, loop
    return (f"| {B} | {npart} | {sub} | {tb * 1e3:.0f} | {hb * 1e3:.0f} | {tl * 1e3:.0f}{mark} | {hl * 1e3:.0f} | "
            f"{tl / tb:.2f} | {tb / B * 1e3:.1f} | {nb:.0f} / {nl:.0f} | {err:.1e} | {f:.3f} | {event:.1f} |")
