"""GaussTac-GraspSqueezeSponge-v1: the scripted expert pinches a free MPM sponge, lifts it
and squeezes it to its target compression; the sponge keeps its volume within what its
material allows, never sinks into the ground, and its Gaussians deform with it; random
actions stay finite; bad settings are refused.

What these guard: the sponge is carried by the pads' grid friction alone (it is not in
SAPIEN), its weight reaches the fingers through tasks/joint_contact.py, and the thumb and
index feel equal and opposite squeezes (the sponge is free between them). The volume bound
is linear elasticity's (below); the compression target is the expert's own servo goal, so
success there checks the task's plumbing, not physics."""
import gymnasium as gym
import numpy as np
import pytest
import torch

import gausstac_maniskill  # noqa: F401  (registers the tasks)
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.experts import make_expert

pytestmark = pytest.mark.sapien
ENV = "GaussTac-GraspSqueezeSponge-v1"


# make test's grid: the sponge's 3 mm cells (4160 particles, 89 substeps per 10 ms) cost a fifth of
# the 2 mm ones (14400, 133) that make bench runs; what these tests guard holds on both
DX = 3e-3


def _make(mpm_dx=DX, **kw):
    kw.setdefault("obs_mode", "state_dict")
    return gym.make(ENV, sim_backend="physx_cpu", mpm_dx=mpm_dx, **kw)


def _volume_ratio(sim) -> np.ndarray:
    """det F of every sponge particle: its current over its rest volume."""
    return np.linalg.det(sim.object_deformation_gradients("sponge"))


@pytest.mark.parametrize("mpm_dx", [DX, pytest.param(2e-3, marks=pytest.mark.slow)])
def test_expert_lifts_and_squeezes_the_sponge(mpm_dx):
    """The expert's episode at make test's 3 mm grid; the 2 mm one (about 14 min of the suite on
    the 2-core CPU) runs in make bench."""
    env = _make(mpm_dx, control_mode="pd_joint_pos")
    try:
        obs, _ = env.reset(seed=0)
        base = env.unwrapped
        sim = base.cosims[0]
        expert = make_expert(env)
        expert.reset()
        for _ in range(80):
            obs, reward, terminated, truncated, info = env.step(expert.act(obs))
            assert torch.isfinite(reward).all()
            x = base.sponge_positions(0)
            assert np.isfinite(x).all()
            assert x[:, 2].min() > -1e-3  # never through the ground (the MPM half-space)
            if info["success"].all():
                break
        assert info["success"].all(), info
        c = float(info["compression"][0])
        assert abs(c - float(base.target_compression[0])) < base.tolerance
        assert float(info["height"][0]) >= base.lift_height
        # free between the pads: the thumb and the index squeeze alike, and together hold the weight
        thumb, index = float(base.touch_force("thumb")[0]), float(base.touch_force("index")[0])
        assert abs(thumb - index) < 0.1 * max(thumb, index), (thumb, index)
        # volume: a squeeze to compression c changes a linear-elastic block's volume by at most
        # (1 - 2 nu) c (uniaxial stress; the sponge away from the pads is unstrained)
        J = _volume_ratio(sim)
        nu = base.sponge_material.nu
        assert J.min() > 0
        assert abs(J.mean() - 1) <= (1 - 2 * nu) * c, (J.mean(), c)
        # the camera draws the sponge with soft Gaussians on its surface particles, which take
        # Sigma = F Sigma0 F^T: the squeezed faces are deformed
        g = sim.group("sponge")
        idx = sim._scene.particle_index
        on_sponge = idx[(idx >= g.start) & (idx < g.stop)]
        assert len(on_sponge) > 0
        F = sim.world.deformation_gradients()[on_sponge]
        assert np.abs(F - np.eye(3)).max() > 0.1
    finally:
        env.close()


@pytest.mark.parametrize("steps, mpm_dx", [(15, DX), pytest.param(300, 2e-3, marks=pytest.mark.slow)])
def test_random_actions_stay_finite(steps, mpm_dx):
    """15 steps at 3 mm in make test; the issue's 300 at 2 mm (about 18 min on the 2-core CPU) in
    make bench."""
    env = _make(mpm_dx, control_mode="pd_joint_delta_pos")
    try:
        env.action_space.seed(0)
        obs, _ = env.reset(seed=0)
        base = env.unwrapped
        for _ in range(steps):
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            assert torch.isfinite(reward).all()
            for pad, maps in obs["tactile"].items():
                assert all(torch.isfinite(m).all() for m in maps.values()), pad
            x = base.sponge_positions(0)
            assert np.isfinite(x).all() and x[:, 2].min() > -1e-3
    finally:
        env.close()


@pytest.mark.parametrize("kw", [dict(sponge_E=1.0), dict(sponge_nu=0.5), dict(sponge_size=(0.02, 0.02)),
                                dict(sponge_size=(0.02, 0.1, 0.02)), dict(compression_range=(0.3, 0.1)),
                                dict(sponge_density="light")])
def test_bad_settings_are_refused(kw):
    with pytest.raises(ConfigError, match=next(iter(kw))):
        _make(**kw)
