"""The force map never reads a pull: every taxel's normal force is ≥ 0 (a project rule).

``GaussTac-Touch-v1`` under random actions (seed 0) presses the kinematic cube 3 mm into the
index pad, whose rim wraps round the cube's side: there the contact normal lies across the
sensor axis and the −z component of the (compressive, frictional) contact force is a pull, which
the edge columns' taxels read without :func:`~gausstac_maniskill.tactile.extract.compressive_force`
(at step 11: 6 taxels, min −24 mN at mpm_dx = 2 mm, the grid used here for speed; 4 taxels,
−19 mN at the default 1 mm)."""
import gymnasium as gym
import numpy as np
import pytest
import torch

import gausstac_maniskill  # noqa: F401  (registers the tasks)

pytestmark = pytest.mark.sapien

SEED, STEPS = 0, 12  # the first negative taxels came at step 11


def _raw_force(fem, name) -> np.ndarray:
    """[H, W] the index pad's force map before compressive_force: the −z component of the
    contact forces binned by footprint (what PadMaps.maps bins)."""
    fp, b = fem.pads[name], fem.binning[name]
    force = fp.result.surface_force
    fn = np.zeros(fp.pad.num_particles)
    np.add.at(fn, fp.point_particles, -(force @ fp.pad.sensor_frame[:3, 2]))
    return b.accumulate((b.taxel >= 0).any(axis=1), fn).reshape(b.rows, b.cols)


def test_touch_force_taxels_are_never_negative_under_random_actions():
    # (mpm_dx = 2 mm: the pad's compliance takes 2 s on a fresh cache instead of 40 s)
    env = gym.make("GaussTac-Touch-v1", obs_mode="state_dict", sim_backend="physx_cpu", mpm_dx=2e-3)
    try:
        env.reset(seed=SEED)
        env.action_space.seed(SEED)
        fem = env.unwrapped._batch.scenes[0].solvers["fem"]
        raw_min, pressed = 0.0, 0.0
        for step in range(STEPS):
            obs, *_ = env.step(env.action_space.sample())
            for pad, maps in obs["tactile"].items():
                f = maps["force"]
                assert torch.isfinite(f).all(), (step, pad)
                assert float(f.min()) >= 0.0, f"step {step}, pad {pad}: taxel force {float(f.min()):.4g} N < 0"
            if fem.pads["index"].result is not None:
                raw = _raw_force(fem, "index")
                total = float(obs["tactile"]["index"]["force"].sum())
                # the pull is moved onto the pressed taxels, not dropped: the total stays
                assert total == pytest.approx(raw.sum(), rel=1e-5, abs=1e-6), step
                raw_min, pressed = min(raw_min, float(raw.min())), max(pressed, total)
        # the case still covers the report: a deep press whose raw edge taxels read a pull
        assert pressed > 10.0 and raw_min < -0.01, (pressed, raw_min)
    finally:
        env.close()
