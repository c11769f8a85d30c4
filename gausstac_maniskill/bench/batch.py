"""``python -m gausstac_maniskill.bench batch`` — B envs in one MPM world against B worlds in a loop.

Every env is the Allegro hand (default pads, default dx = 1 mm), a little moved, with a
6 mm ball pressed into its index pad (0.4 to 0.9 mm, a different depth per env) over
``--steps`` control steps of 20 ms. For each B (``--envs``) the same scenes run two ways:

* **batched**: :class:`~gausstac_maniskill.batch.BatchedCosim`, one world, one set of launches;
* **loop**: B :class:`~gausstac_maniskill.cosim.GaussTacSim` stepped one after the other
  (what ``GaussTacEnv`` does today), each with the batch's substeps.

Prints per B: wall time per control step of both (the first step, which compiles, is left
out), the ratio measured in this run, Taichi launches per step of both, and the error of the
batch: the largest difference of env 0's maps from the same scene alone, over their
largest value. Taichi arch: ``GAUSSTAC_ARCH`` (cpu by default).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

R = 6e-3
DT = 0.02
KERNELS = ("prepare", "advance", "fbar_update", "reduce_contact", "follow_links", "reset_contact", "chunk_health")


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
    """Counts the MPM kernel launches (wraps the kernels module's functions)."""

    def __init__(self):
        from ..mpm import kernels as K

        self.K, self.n, self._orig = K, 0, {}
        for name in KERNELS:
            f = self._orig[name] = getattr(K, name)

            def counted(*a, _f=f, **kw):
                self.n += 1
                return _f(*a, **kw)

            setattr(K, name, counted)

    def close(self):
        for name, f in self._orig.items():
            setattr(self.K, name, f)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m gausstac_maniskill.bench batch", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--envs", type=int, nargs="+", default=[1, 4, 16], help="env counts B (default: 1 4 16)")
    ap.add_argument("--steps", type=int, default=6, help="control steps of 20 ms per run (default: 6)")
    ap.add_argument("--dx", type=float, default=1e-3, help="grid spacing [m] (default: 1 mm, the product's)")
    ap.add_argument("--loop-max", type=int, default=64,
                    help="run the loop of single worlds only up to this B (default: 64); above it, only the batch")
    args = ap.parse_args(argv)
    from tqdm import tqdm

    from .. import backend
    from ..batch import BatchedCosim
    from ..cosim import GaussTacSim, default_hand_settings
    from ..mpm import Sphere
    from ..pose import MujocoPoseSource
    from ..tactile import allegro_pad_specs

    arch = backend.ensure_init()
    pads = allegro_pad_specs()
    names = [p.link for p in pads]
    base = MujocoPoseSource().link_poses(names)[0].double().numpy()
    settings = default_hand_settings(dx=args.dx)
    sensor = GaussTacSim(pads, dict(zip(names, base)), settings=settings).pads["link_3.0_tip"].sensor_frame
    print(f"\nBatched co-simulator, Allegro index pad pressed by a 6 mm ball in every env, dx = {args.dx * 1e3:g} mm, "
          f"Taichi {arch}, {args.steps - 1} timed steps of {DT * 1e3:g} ms")
    print("| B | particles | substeps | batched [ms/step] | loop [ms/step] | loop / batched | batched per env "
          "[ms] | launches batched / loop | env 0 vs alone (max rel) | mean index force [N] |")
    print("|---|---|---|---|---|---|---|---|---|---|", flush=True)
    for B in tqdm(args.envs, desc="env counts", unit="B"):  # each row as it is measured: a cut run keeps them
        scenes = _scenes(B, names, base, sensor)
        poses = np.stack([P for P, _ in scenes])
        batch = BatchedCosim(pads, names, poses, settings=settings)
        batch.add_rigid_object("ball", [Sphere(radius=R, pose=c(-1), friction=0.5) for _, c in scenes])
        loop = []
        for P, c in (scenes if B <= args.loop_max else scenes[:1]):
            sim = GaussTacSim(pads, dict(zip(names, P)), settings=settings)
            sim.add_rigid_object("ball", Sphere(radius=R, pose=c(-1), friction=0.5))
            loop.append(sim)
        t_batch = t_loop = 0.0
        n_batch = n_loop = 0
        for k in range(args.steps):
            counter = _Launches()
            t0 = time.perf_counter()
            maps = batch.step(poses, DT, {"ball": np.stack([c(k) for _, c in scenes])})
            t1 = time.perf_counter()
            nb = counter.n
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
                n_batch += nb
                n_loop += counter.n - nb
        alone = loop[0].tactile()
        err = max(float((maps[p][key][0] - alone[p][key]).abs().max()) / max(float(alone[p][key].abs().max()), 1e-30)
                  for p in batch.pad_names for key in ("depth", "shear", "force") if alone[p][key].abs().max() > 0)
        force = float(maps["link_3.0_tip"]["force"].sum(dim=(1, 2)).mean())
        n = args.steps - 1
        est = len(loop) < B  # the loop ran env 0 alone: B times its time and launches, an estimate
        scale = B if est else 1
        tqdm.write(_row(B, batch.world.last_step.active_particles, sub, t_batch / n, scale * t_loop / n,
                        n_batch / n, scale * n_loop / n, err, force, est))
    return 0


def _row(B, npart, sub, tb, tl, nb, nl, err, f, est) -> str:
    mark = " (B × env 0 alone)" if est else ""
    return (f"| {B} | {npart} | {sub} | {tb * 1e3:.0f} | {tl * 1e3:.0f}{mark} | {tl / tb:.2f} | {tb / B * 1e3:.1f} | "
            f"{nb:.0f} / {nl:.0f} | {err:.1e} | {f:.3f} |")
