"""The task argument and action checks: each refuses a bad value with a ``ConfigError`` naming the
task, the argument and the value, and accepts what the tasks document (no env is built)."""
import numpy as np
import pytest
import torch

from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.task_checks import (check_action, check_choice, check_flag, check_pair, check_range,
                                            check_render_mode, check_sim_backend, check_size, check_splat_look,
                                            is_integer, is_real)

T = "GaussTac-Test-v1"


def test_range_accepts_real_numbers_inside_and_names_a_bad_value():
    check_range(T, "mass", 0.5, 0.0, 1.0, "kg")
    check_range(T, "mass", np.float32(1.0), 0.0, 1.0)
    for bad in (1.5, float("nan"), True, "0.5", None):
        with pytest.raises(ConfigError, match=r"GaussTac-Test-v1: mass=.* must be a number in \[0, 1\] kg"):
            check_range(T, "mass", bad, 0.0, 1.0, "kg")
    with pytest.raises(ConfigError, match=r"must be a number in \[0, 1\]$"):
        check_range(T, "mu", 2.0, 0.0, 1.0)  # no unit: no trailing blank


def test_pair_returns_floats_and_refuses_an_unordered_or_short_pair():
    assert check_pair(T, "span", (1, 2), 0.0, 3.0) == (1.0, 2.0)
    assert all(type(v) is float for v in check_pair(T, "span", np.array([0.5, 0.5]), 0.0, 1.0))
    for bad in ((2, 1), (1,), 3, (0, 5), (True, 1)):
        with pytest.raises(ConfigError, match=r"span=.* must be two numbers \(lo, hi\) with 0 <= lo <= hi <= 3 m"):
            check_pair(T, "span", bad, 0.0, 3.0, "m")


def test_flag_choice_and_size():
    check_flag(T, "lod", np.bool_(True))
    with pytest.raises(ConfigError, match="lod='no' must be True or False"):
        check_flag(T, "lod", "no")
    check_choice(T, "model", "a", ("a", "b"))
    with pytest.raises(ConfigError, match="model='c' must be one of 'a', 'b'"):
        check_choice(T, "model", "c", ("a", "b"))
    check_size(T, "splat_size", (np.int64(64), 8192))
    for bad in ((0, 4), (4.0, 4), (True, 4), (4,), 4):
        with pytest.raises(ConfigError, match=r"splat_size=.* must be \(width, height\), two integers in \[1, 8192\]"):
            check_size(T, "splat_size", bad)


def test_real_and_integer_predicates():
    assert is_real(1) and is_real(np.float64(1.0)) and not is_real(True) and not is_real(np.bool_(False))
    assert is_integer(torch.int64) and is_integer(torch.uint8)
    assert not is_integer(torch.float32) and not is_integer(torch.bool) and not is_integer(torch.complex64)


def test_action_is_cast_to_float32_or_refused_naming_shape_and_dtype():
    a = check_action(T, np.arange(3), (3,), 2, "pd_joint_pos", "cpu")
    assert a.dtype == torch.float32 and a.tolist() == [0.0, 1.0, 2.0]
    assert check_action(T, [[0.0] * 3] * 2, (3,), 2, "pd_joint_pos", "cpu").shape == (2, 3)
    assert check_action(T, None, (3,), 2, "m", "cpu") is None
    d = {"a": 1}
    assert check_action(T, d, (3,), 2, "m", "cpu") is d
    with pytest.raises(ConfigError, match=r"action of shape \(4,\); control_mode 'pd_joint_pos' expects shape "
                                          r"\(3,\) or \(2, 3\) \(num_envs=2\); nothing was stepped"):
        check_action(T, np.zeros(4), (3,), 2, "pd_joint_pos", "cpu")
    with pytest.raises(ConfigError, match="action of dtype torch.bool"):
        check_action(T, np.zeros(3, bool), (3,), 2, "m", "cpu")
    with pytest.raises(ConfigError, match="action of type object is not an array of numbers"):
        check_action(T, object(), (3,), 2, "m", "cpu")
    with pytest.raises(ConfigError, match=r"action contains NaN or inf at \[\[1\]\]"):
        check_action(T, [0.0, float("inf"), 0.0], (3,), 2, "m", "cpu")


def test_render_mode_splat_look_and_sim_backend(monkeypatch):
    check_render_mode(T, None)
    check_render_mode(T, "rgb_array")
    with pytest.raises(ConfigError, match="render_mode='movie' must be None or one of"):
        check_render_mode(T, "movie")
    check_splat_look(T, None, "scene")
    check_splat_look(T, "sapien", "baked")
    check_splat_look(T, (0.0, 0.5, 1.0), "scene")
    with pytest.raises(ConfigError, match="splat_lighting='sun' must be 'scene', 'baked' or a"):
        check_splat_look(T, None, "sun")
    for bad in ("black", (0, 0), (0, 0, 2), (0, float("nan"), 0)):
        with pytest.raises(ConfigError, match="splat_background=.* must be None, 'sapien' or an RGB triple"):
            check_splat_look(T, bad, "scene")
    check_sim_backend(1, "physx_cpu")
    for bad in (0, True, 1.0):
        with pytest.raises(ConfigError, match="num_envs=.* must be a positive integer"):
            check_sim_backend(bad, "auto")
    with pytest.raises(ConfigError, match="ManiSkill simulates several envs in one process only on an NVIDIA GPU"):
        check_sim_backend(2, "physx_cpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ConfigError, match="needs an NVIDIA GPU with CUDA"):
        check_sim_backend(1, "physx_cuda")


def test_pad_coupling_against_the_simulation():
    from gausstac_maniskill.task_checks import check_pad_coupling

    check_pad_coupling(None, True, True, 100, 2000)
    check_pad_coupling("implicit", False, False, 100, 2000)
    with pytest.raises(ConfigError, match="pad_reaction=True needs sim_backend='physx_cpu'"):
        check_pad_coupling("explicit", True, False, 5000, 2000)
    with pytest.raises(ConfigError, match="pad_reaction=True needs PhysX's PGS solver"):
        check_pad_coupling("implicit", False, True, 100, 2000)

    def caller():
        check_pad_coupling("explicit", False, True, 100, 2000)

    with pytest.warns(UserWarning, match="pad_reaction='explicit' at sim_freq=100 Hz: .* stable from 2000 Hz") as rec:
        caller()  # attributed to caller's caller, this line
    assert rec[0].filename == __file__ and rec[0].lineno == caller.__code__.co_firstlineno + 4
