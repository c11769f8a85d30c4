"""Replay by env states is bit-exact: a step taken from a restored env state (what ManiSkill's replay
with --use-env-states does at every step) is the recorded step, observations and state, bit for bit
(CPU sim, same machine), and the task's float64 state comes back as float64."""
import copy

import gymnasium as gym
import numpy as np
import torch

import gausstac_maniskill
from gausstac_maniskill.tactile_env import copied, split_task_state

gausstac_maniskill.register()
TASK = "GaussTac-PressCube-v1"


def _leaves(tree, prefix=""):
    for k, v in tree.items():
        if isinstance(v, dict):
            yield from _leaves(v, f"{prefix}{k}/")
        else:
            yield prefix + k, np.asarray(v.cpu() if isinstance(v, torch.Tensor) else v)


def _assert_same(got: dict, want: dict, where) -> None:
    want = dict(_leaves(want))
    got = dict(_leaves(got))
    assert sorted(got) == sorted(want), where
    for k, w in want.items():
        assert got[k].dtype == w.dtype and np.array_equal(got[k], w, equal_nan=w.dtype.kind == "f"), (where, k)


def test_task_state_leaves_keep_float64():
    """The "task" part of the env state (face frames, wrenches, pad contacts: float64) is
    restored bit for bit, from tensors and from the numpy arrays an h5 file gives."""
    x = torch.tensor([[0.1, 0.0512345678901]], dtype=torch.float64)
    for leaf in (x, x.numpy()):
        task, wrench, contacts = split_task_state({"face_frame": leaf, "wrench_cube": leaf, "pad_contacts": leaf},
                                                  torch.arange(1), 1, lambda: {})
        for v in (task["face_frame"], wrench["cube"], contacts):
            assert v.dtype == torch.float64 and torch.equal(v, x)


def test_a_step_from_a_restored_state_is_the_recorded_step():
    """What ManiSkill's replay by env states does at every step t: set_state_dict(env_states[t]),
    step(actions[t]), record the observation: it is the recorded step t + 1's, and so is the env
    state, bit for bit. Seeds 0 and 1 at mpm_dx=2e-3 each had a step (the 4th) whose qpos
    (8.5e-13) or index tactile maps (5.1e-7 N) differed before the fix."""
    from gausstac_maniskill.experts import make_expert

    kw = dict(obs_mode="state_dict", sim_backend="physx_cpu", mpm_dx=2e-3, control_mode="pd_joint_delta_pos")
    rec, rep = gym.make(TASK, **kw), gym.make(TASK, **kw)
    try:
        expert = make_expert(rec)
        touched = 0.0
        for seed in (0, 1):
            obs, _ = rec.reset(seed=seed)
            expert.reset()
            states, observations, actions = [copied(rec.unwrapped.get_state_dict())], [None], []
            for _ in range(8):
                action = expert.act(obs)
                obs, _, terminated, _, _ = rec.step(action)
                actions.append(torch.as_tensor(action).clone())
                states.append(copied(rec.unwrapped.get_state_dict()))
                observations.append(copied(rec.unwrapped.get_obs(unflattened=True)))
                if bool(terminated.any()):
                    break
            rep.reset(seed=seed)
            for t, action in enumerate(actions):
                rep.unwrapped.set_state_dict(copy.deepcopy(states[t]))
                rep.step(action)
                _assert_same(rep.unwrapped.get_obs(unflattened=True), observations[t + 1], (seed, t + 1, "obs"))
                _assert_same(rep.unwrapped.get_state_dict(), states[t + 1], (seed, t + 1, "state"))
                touched += float(observations[t + 1]["tactile"]["index"]["force"].sum())
        assert touched > 1.0  # the steps compared include pressed index maps
    finally:
        rec.close()
        rep.close()
