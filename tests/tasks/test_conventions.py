"""Gymnasium/ManiSkill conventions every GaussTac task keeps.

* Observations and infos are copies: a kept ``reset``/``step`` result never changes when the
  env is reset or stepped again, and none of its tensors shares memory with the env's state
  (task targets, the tactile maps ``env.tactile()`` keeps, the controller's targets) or with
  another observation (the ``check_step_determinism`` idea of gymnasium's env checker, with
  its ``data_equivalence``).
* Actions: integer arrays are cast to float32; a wrong shape, a non-numeric dtype, NaN or inf
  get a ``ConfigError`` that names the expected and the given shape or dtype, and nothing is
  stepped.
* Every task argument is checked in the task's constructor: a bad value gets a
  ``ConfigError`` naming the argument and the value given (not a field of an inner object).
* ``render_mode="human"`` without a display is refused in ``gym.make``, naming ``rgb_array``.
* The scripted experts hand torch no read-only NumPy array (torch warns "array is not
  writable" and shares the memory).

Envs at ``mpm_dx=3e-3``, the coarsest grid the tests use: these check plumbing, not physics.
"""
import contextlib
import inspect
import re
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import data_equivalence
from mani_skill.utils import common

import gausstac_maniskill  # noqa: F401  (registers the tasks)
from gausstac_maniskill.errors import ConfigError, ResolutionWarning
from gausstac_maniskill.experts import EXPERTS, make_expert
from gausstac_maniskill.tasks.base import GaussTacEnv

pytestmark = pytest.mark.sapien

DX = 3e-3
TASKS = ["GaussTac-Gesture-v1", "GaussTac-Touch-v1", "GaussTac-PressCube-v1", "GaussTac-SlideCube-v1",
         "GaussTac-SqueezeSponge-v1", "GaussTac-GraspLiftCube-v1", "GaussTac-GraspSqueezeSponge-v1"]


def _make(env_id, **kw):
    kw.setdefault("obs_mode", "state_dict")
    kw.setdefault("mpm_dx", DX)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ResolutionWarning: 3 mm cells under-resolve the pads (known)
        return gym.make(env_id, sim_backend="physx_cpu", **kw)


@pytest.fixture(scope="module", params=TASKS)
def task_env(request):
    env = _make(request.param, control_mode="pd_joint_delta_pos")
    yield request.param, env
    env.close()


def _leaves(tree):
    if isinstance(tree, dict):
        for v in tree.values():
            yield from _leaves(v)
    elif isinstance(tree, torch.Tensor) and tree.numel():
        yield tree


def _storages(tree) -> set[int]:
    return {t.untyped_storage().data_ptr() for t in _leaves(tree)}


def _env_state_storages(base) -> set[int]:
    """Memory of the env's live tensors: its attributes (task targets and progress), the tactile
    maps it keeps, and the controller's state (e.g. its joint targets)."""
    live = {k: v for k, v in vars(base).items() if isinstance(v, torch.Tensor)}
    live["tactile"] = base.tactile()
    live["controller"] = {k: v for k, v in vars(base.agent.controller).items() if isinstance(v, torch.Tensor)}
    return _storages(live)


def _snapshot(tree):
    """A numpy deep copy of an obs/info tree (what the caller saw; ``to_numpy`` alone shares a
    CPU tensor's memory)."""
    if isinstance(tree, dict):
        return {k: _snapshot(v) for k, v in tree.items()}
    return np.array(common.to_numpy(tree), copy=True)


def _zero_action(env):
    return np.zeros(env.action_space.shape, np.float32)


def test_kept_reset_and_step_results_never_change(task_env):
    """reset(seed=8)'s obs and info, kept, read the same after another reset and steps; no tensor
    of them shares memory with the env's state (e.g. PressCube's ``target_force``,
    SqueezeSponge's ``target_compression``, SlideCube's ``lost`` behind ``info["fail"]``, the
    tactile maps behind ``obs["tactile"]``) or with a later step's obs and info."""
    env_id, env = task_env
    base = env.unwrapped
    obs0, info0 = env.reset(seed=8)
    snap_obs, snap_info = _snapshot(obs0), _snapshot(info0)
    kept = {"obs": obs0, "info": info0}
    shared = _storages(kept) & _env_state_storages(base)
    assert not shared, f"{env_id}: reset results share memory with the env's state"
    env.reset(seed=9)
    obs1, _, _, _, info1 = env.step(_zero_action(env))
    assert not _storages(kept) & _storages({"obs": obs1, "info": info1}), f"{env_id}: step reuses reset's tensors"
    assert not _storages({"obs": obs1, "info": info1}) & _env_state_storages(base), env_id
    env.step(_zero_action(env))
    assert data_equivalence(_snapshot(obs0), snap_obs), f"{env_id}: the kept reset observation changed"
    assert data_equivalence(_snapshot(info0), snap_info), f"{env_id}: the kept reset info changed"
    # and gymnasium's check_reset_seed_determinism: the same seed gives the same observation
    obs2, _ = env.reset(seed=8)
    assert data_equivalence(_snapshot(obs2), snap_obs), f"{env_id}: reset(seed=8) is not reproducible"


def test_camera_observations_are_copies():
    """With a splat camera (obs_mode rgb): two get_obs() of the same state (the camera keeps its
    picture until the next capture) and the reset obs share no memory; the kept reset picture
    reads the same after a step."""
    env = _make("GaussTac-Gesture-v1", obs_mode="rgb", splat_size=(32, 32))
    try:
        obs0, _ = env.reset(seed=8)
        snap = _snapshot(obs0)
        again = env.unwrapped.get_obs()
        assert not _storages(obs0) & _storages(again)
        env.step(_zero_action(env))
        assert data_equivalence(_snapshot(obs0), snap)
    finally:
        env.close()


@contextlib.contextmanager
def _watch_conversions(read_only: list):
    """While inside, torch's array-sharing conversions record every read-only NumPy array given."""
    saved = {name: getattr(torch, name) for name in ("as_tensor", "from_numpy", "asarray")}

    def watch(fn):
        def converted(data, *args, **kwargs):
            if isinstance(data, np.ndarray) and not data.flags.writeable:
                read_only.append((fn.__name__, data.shape, data.dtype))
            return fn(data, *args, **kwargs)
        return converted

    try:
        for name, fn in saved.items():
            setattr(torch, name, watch(fn))
        yield
    finally:
        for name, fn in saved.items():
            setattr(torch, name, fn)


@contextlib.contextmanager
def _strict_warnings():
    """Every warning an error, but the pads' ResolutionWarning (3 mm cells under-resolve them:
    known, and raised by the env's pad geometry the expert's IK reads)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.simplefilter("ignore", ResolutionWarning)
        yield


def test_expert_hands_torch_no_read_only_array(task_env):
    """The expert's reset and two acts (delta joint control) pass torch no read-only NumPy array
    (``np.broadcast_to`` makes one) and raise no warning. torch warns about such an array only
    once per process, so the conversions themselves are watched."""
    env_id, env = task_env
    if env_id not in EXPERTS:
        pytest.skip(f"{env_id} has no scripted expert")
    read_only = []
    obs, _ = env.reset(seed=1)
    expert = make_expert(env)
    with _strict_warnings(), _watch_conversions(read_only):
        expert.reset()
    for _ in range(2):
        with _strict_warnings(), _watch_conversions(read_only):
            action = expert.act(obs)
        obs = env.step(action)[0]
    assert not read_only, f"{env_id}'s expert gave torch read-only arrays: {read_only}"


# ------------------------------------------------------------------ actions
@pytest.fixture(scope="module")
def gesture_env():
    env = _make("GaussTac-Gesture-v1", control_mode="pd_joint_delta_pos")
    env.reset(seed=0)
    yield env
    env.close()


@pytest.mark.parametrize("action", [np.zeros(3, np.float32), np.zeros((2, 16), np.float32),
                                    np.zeros((1, 1, 16), np.float32), torch.zeros(15)],
                         ids=["(3,)", "(2, 16)", "(1, 1, 16)", "torch (15,)"])
def test_action_of_a_wrong_shape_names_the_expected_one(gesture_env, action):
    """ManiSkill's own answer is a bare AssertionError from its controller."""
    base = gesture_env.unwrapped
    steps, q = int(base.elapsed_steps[0]), base.agent.robot.get_qpos().clone()
    given = re.escape(str(tuple(action.shape)))
    with pytest.raises(ConfigError, match=rf"shape {given}.*pd_joint_delta_pos.*expects shape \(16,\) or \(1, 16\)"):
        gesture_env.step(action)
    assert int(base.elapsed_steps[0]) == steps and torch.equal(base.agent.robot.get_qpos(), q)


@pytest.mark.parametrize("convert", [lambda a: a.astype(np.int64), lambda a: torch.as_tensor(a).to(torch.int32),
                                     lambda a: a.astype(int).tolist()], ids=["int64", "torch int32", "list"])
def test_integer_and_list_actions_are_cast_to_float32(gesture_env, convert, monkeypatch):
    """An integer (or list) action is cast: it reaches the controller as the same values in
    float32, on the env's device, and the env steps."""
    base = gesture_env.unwrapped
    received = []
    set_action = base.agent.set_action
    monkeypatch.setattr(base.agent, "set_action", lambda a: (received.append(a.clone()), set_action(a))[1])
    gesture_env.action_space.seed(3)
    a = np.round(gesture_env.action_space.sample()).astype(np.float32)  # -1, 0, 1: integers can hold them
    assert np.any(a != 0)
    steps = int(base.elapsed_steps[0])
    gesture_env.step(convert(a))
    assert int(base.elapsed_steps[0]) == steps + 1
    (got,) = received
    assert got.dtype == torch.float32 and got.device == base.device
    assert torch.equal(got, torch.as_tensor(a).reshape(got.shape))


@pytest.mark.parametrize("action, match", [
    (np.zeros((1, 16), bool), r"dtype torch\.bool.*float32"),
    (np.zeros((1, 16), np.complex64), r"dtype torch\.complex64.*float32"),
    (np.array([["a"] * 16]), r"not an array of numbers"),
    (np.full((1, 16), np.inf, np.float32), r"NaN or inf at \[\[0, 0\]"),
])
def test_action_of_a_wrong_dtype_or_value_is_named(gesture_env, action, match):
    base = gesture_env.unwrapped
    steps = int(base.elapsed_steps[0])
    with pytest.raises(ConfigError, match=match):
        gesture_env.step(action)
    assert int(base.elapsed_steps[0]) == steps


# ------------------------------------------------------------------ constructor arguments
BASE = "GaussTac-Gesture-v1"
SQUEEZE, TOUCH, LIFT, GRASP_SPONGE = ("GaussTac-SqueezeSponge-v1", "GaussTac-Touch-v1", "GaussTac-GraspLiftCube-v1",
                                      "GaussTac-GraspSqueezeSponge-v1")
BAD = [
    # GaussTacEnv's own (on the cheapest task)
    (BASE, "mpm_dx", 0.5), (BASE, "mpm_sleep_margin", -1.0), (BASE, "splat_size", (0, 128)),
    (BASE, "render_size", "big"), (BASE, "splat_background", "blue"), (BASE, "splat_lighting", "sun"),
    (BASE, "record_mpm_state", "no"), (BASE, "splat_lod", None), (BASE, "splat_cull", "yes"),
    (BASE, "camera", "pinhole"), (BASE, "pad_reaction", "yes"), (BASE, "pad_solver", "implicit"),
    (BASE, "fem_model", "stvk"), (BASE, "fem_precompute", "auto"), (BASE, "num_envs", 0),
    (BASE, "render_mode", "video"), (BASE, "optical", "gelsite"), (BASE, "optical", {"index": 3}),
    (BASE, "optical_width", 3),
    ("GaussTac-Gesture-v1", "gesture", "wave"), ("GaussTac-Gesture-v1", "tolerance", 0.0),
    ("GaussTac-PressCube-v1", "tolerance", 2.0), ("GaussTac-PressCube-v1", "force_range", (2.0, 1.0)),
    ("GaussTac-PressCube-v1", "force_range", "strong"),
    ("GaussTac-SlideCube-v1", "contact_force", -1.0), ("GaussTac-SlideCube-v1", "distance_range", (0.01, 0.5)),
    (SQUEEZE, "sponge_nu", 0.5), (SQUEEZE, "sponge_E", 1.0), (SQUEEZE, "sponge_density", "light"),
    (SQUEEZE, "sponge_model", "jelly"), (SQUEEZE, "sponge_thickness", 0.1), (SQUEEZE, "compression_range", (0.3, 0.1)),
    (SQUEEZE, "tolerance", 0.9),
    (TOUCH, "touch_pad", 3), (TOUCH, "cube_half_size", 0.0), (TOUCH, "cube_gap", 1.0), (TOUCH, "free_cube", "yes"),
    (TOUCH, "two_way", "no"), (TOUCH, "cube_density", 0.0), (TOUCH, "cube_friction", -0.1), (TOUCH, "ground", "no"),
    (TOUCH, "ground_altitude", 0.5), (TOUCH, "force_threshold", -1.0), (TOUCH, "init_qpos", "open"),
    (TOUCH, "pad_reaction", "yes"),
    (LIFT, "lift_height", 1.0), (LIFT, "hold_time", -1.0), (LIFT, "grasp_force", -1.0), (LIFT, "approach_height", 1.0),
    (LIFT, "xy_range", 1.0), (LIFT, "cube_mass", 10.0), (LIFT, "cube_half_size", 0.1), (LIFT, "cube_friction", -1.0),
    (LIFT, "pad_reaction", "yes"),
    (GRASP_SPONGE, "sponge_E", 1.0), (GRASP_SPONGE, "sponge_nu", 0.5), (GRASP_SPONGE, "sponge_density", "light"),
    (GRASP_SPONGE, "sponge_model", "jelly"), (GRASP_SPONGE, "sponge_size", (0.02, 0.02)),
    (GRASP_SPONGE, "sponge_friction", -1.0), (GRASP_SPONGE, "compression_range", (0.3, 0.1)),
    (GRASP_SPONGE, "tolerance", 0.0), (GRASP_SPONGE, "lift_height", 1.0), (GRASP_SPONGE, "hold_time", -1.0),
]
#: arguments whose refusals other tests check (a file to read, or a check that needs the built agent)
ELSEWHERE = {"robot_uids": "test_tasks.py::test_non_gausstac_robot_is_refused",
             "scene_ply": "test_captured_scene.py", "scene_pose": "test_captured_scene.py"}


@pytest.mark.parametrize("env_id, name, value", BAD, ids=[f"{e.split('-')[1]}-{n}={v!r}" for e, n, v in BAD])
def test_bad_task_argument_is_named_in_its_error(env_id, name, value):
    """The message names the argument and the value given, and says what is expected (e.g.
    ``sponge_nu=0.5``, not ``Material.nu``); nothing is built first."""
    with pytest.raises(ConfigError) as err:
        _make(env_id, **{name: value})
    msg = str(err.value)
    assert f"{name}={value!r}" in msg, msg
    assert re.search(r"must|use|choose", msg), msg


@pytest.mark.parametrize("env_id", TASKS)
def test_every_constructor_argument_has_a_bad_value_case(env_id):
    """A new task argument without a case in ``BAD`` (or ``ELSEWHERE``) fails here."""
    from mani_skill.utils.registration import REGISTERED_ENVS

    missing = []
    for cls in REGISTERED_ENVS[env_id].cls.__mro__:
        if not (isinstance(cls, type) and issubclass(cls, GaussTacEnv)):
            break
        if "__init__" not in vars(cls):
            continue  # its parameters are its base class's
        for p in inspect.signature(cls.__init__).parameters.values():
            if p.kind not in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD) or p.name == "self" or p.name in ELSEWHERE:
                continue
            # a case on any task that has this class's constructor covers it
            if not any(n == p.name and issubclass(REGISTERED_ENVS[e].cls, cls) for e, n, _ in BAD):
                missing.append(f"{cls.__name__}.{p.name}")
    assert not missing, f"{env_id}: no bad-value case for {missing}"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="display variables are X11/Wayland's")
def test_human_render_mode_without_a_display_names_rgb_array(monkeypatch):
    """SAPIEN's own failure comes from deep inside gym.make."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(ConfigError, match=r"render_mode='human'.*no display.*DISPLAY.*render_mode='rgb_array'"):
        _make("GaussTac-Gesture-v1", render_mode="human")
