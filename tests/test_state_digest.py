"""Refactor guard: the state after a pad scene and a task scene is bit-identical to a recorded digest.

This compares the code with an earlier version of itself, not with physics: it guards moves and
splits that must not change arithmetic. Each scene is digested in parts: what it reads out (tactile
maps, wrenches, observations) apart from the layout of its saved state, so that a change of the
state's layout alone shows as such. A change that is meant to change the numbers records new
digests, and says so in its commit:

    GAUSSTAC_COMPILE=fast python tests/test_state_digest.py --record

The digests depend on the machine's instruction set and on the compile mode, so they are kept per
machine key; on a machine without a recorded key the test skips and names the command above.
"""
from __future__ import annotations

import hashlib
import json
import platform
import sys
from pathlib import Path

import numpy as np
import pytest

from gausstac_maniskill import environment

DIGESTS = Path(__file__).with_name("data") / "state_digests.json"
INDEX = "link_3.0_tip"


def machine_key() -> str:
    """Processor model, instruction-set flags and compile mode: what the bits depend on."""
    flags, model = "", platform.processor()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags") and not flags:
                flags = hashlib.sha256(line.split(":", 1)[1].strip().encode()).hexdigest()[:12]
            if line.startswith("model name") and model == platform.processor():
                model = line.split(":", 1)[1].strip()
    except OSError:
        pass
    return f"{platform.machine()}|{model}|flags:{flags}|compile:{environment.read('GAUSSTAC_COMPILE') or 'product'}"


def digest(arrays: dict) -> str:
    """sha256 over the sorted leaves (name, dtype, shape, bytes) of a nested dict of arrays."""
    h = hashlib.sha256()

    def walk(prefix, value):
        if isinstance(value, dict):
            for k in sorted(value):
                walk(f"{prefix}/{k}", value[k])
            return
        a = np.ascontiguousarray(value.detach().cpu().numpy() if hasattr(value, "detach") else np.asarray(value))
        h.update(f"{prefix}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())

    walk("", arrays)
    return h.hexdigest()


def _hand_poses():
    from gausstac_maniskill.pose import MujocoPoseSource
    from gausstac_maniskill.tactile import allegro_pad_specs

    names = [s.link for s in allegro_pad_specs()]
    return dict(zip(names, MujocoPoseSource().link_poses(names)[0].numpy()))


def pad_scene(pad_solver: str) -> dict:
    """A 6 mm sphere pressed 0.8 mm into the Allegro index pad over 10 steps of 20 ms."""
    from gausstac_maniskill.config import SolverSettings
    from gausstac_maniskill.cosim import GaussTacSim
    from gausstac_maniskill.mpm import Sphere
    from gausstac_maniskill.tactile import allegro_pad_specs
    from gausstac_maniskill.transforms import make_pose

    poses = _hand_poses()
    dx = 1.0e-3 if pad_solver == "auto" else 1.5e-3
    sim = GaussTacSim(allegro_pad_specs(), poses, settings=SolverSettings(dx=dx), pad_solver=pad_solver)
    W = poses[INDEX] @ sim.pads[INDEX].sensor_frame
    R = 6e-3
    centre = lambda d: make_pose(W[:3, 3] + W[:3, 2] * (R - d))  # noqa: E731
    sim.add_rigid_object("ball", Sphere(radius=R, pose=centre(-0.5e-3), friction=0.5))
    for k in range(10):
        sim.step(poses, 0.02, {"ball": centre(0.8e-3 * min(1.0, (k + 1) / 8))})
    return {"state": sim.flat_state(), "tactile": sim.tactile(), "wrench": np.concatenate(sim.object_wrench("ball"))}


def task_scene() -> dict:
    """GaussTac-PressCube-v1 on physx_cpu: reset(seed=0) and 4 steps of its scripted expert."""
    import gymnasium as gym

    import gausstac_maniskill  # noqa: F401  (registers the tasks)
    from gausstac_maniskill.experts import make_expert

    env = gym.make("GaussTac-PressCube-v1", sim_backend="physx_cpu", obs_mode="state_dict",
                   control_mode="pd_joint_delta_pos")
    try:
        obs, _ = env.reset(seed=0)
        expert = make_expert(env)
        expert.reset()
        for _ in range(4):
            obs, *_ = env.step(expert.act(obs))
        return {"obs": obs, "state": env.unwrapped.get_state_dict()}
    finally:
        env.close()


SCENES = {"fem_pad": lambda: pad_scene("auto"), "mpm_pad": lambda: pad_scene("mpm"), "task": task_scene}


def recorded() -> dict:
    return json.loads(DIGESTS.read_text()) if DIGESTS.exists() else {}


def digests(scene: str) -> dict[str, str]:
    """One digest per part of the scene's result (tactile, wrench, obs, state)."""
    return {part: digest(value) for part, value in SCENES[scene]().items()}


@pytest.mark.parametrize("scene", [s for s in SCENES if s != "task"] +
                         [pytest.param("task", marks=pytest.mark.sapien)])
def test_state_is_bit_identical_to_the_recorded_digest(scene):
    key = machine_key()
    expected = recorded().get(key, {}).get(scene)
    if expected is None:
        pytest.skip(f"no digest recorded for {scene!r} on {key}: run "
                    "`GAUSSTAC_COMPILE=fast python tests/test_state_digest.py --record`")
    got = digests(scene)
    differ = sorted(part for part in expected if got.get(part) != expected[part])
    assert not differ and set(got) == set(expected), (
        f"{scene}: {differ or sorted(set(got) ^ set(expected))} differ from the recorded digests; if the "
        "change is meant to change them, record new digests (see this module's docstring) and say so in the commit")


if __name__ == "__main__":
    if "--record" not in sys.argv:
        raise SystemExit(__doc__)
    only = [a for a in sys.argv[1:] if a in SCENES] or list(SCENES)
    data = recorded()
    key = machine_key()
    for name in only:
        data.setdefault(key, {})[name] = digests(name)
        print(f"{name}: {data[key][name]}")
    DIGESTS.parent.mkdir(exist_ok=True)
    DIGESTS.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    print("wrote", DIGESTS, "for", key)
