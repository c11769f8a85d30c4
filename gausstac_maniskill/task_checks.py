"""Argument and action checks of the GaussTac tasks: each raises a ``ConfigError`` that names
the task, the argument and the value given, before ManiSkill, SAPIEN or the co-simulator meet
the value and fail with a bare error.

* :func:`check_range`, :func:`check_pair`, :func:`check_flag`, :func:`check_choice`,
  :func:`check_size`: one task argument each (numbers, bools, choices, image sizes).
* :func:`check_render_mode`, :func:`check_splat_look`, :func:`check_sim_backend`: the
  ``BaseEnv`` and splat-camera arguments of :class:`~gausstac_maniskill.tasks.base.GaussTacEnv`.
* :func:`check_pad_coupling`: ``pad_reaction`` against the simulation ManiSkill set up.
* :func:`check_action`: the action of one ``env.step``.
"""
from __future__ import annotations

import numbers
import os
import sys
import warnings

import numpy as np
import torch
from mani_skill.envs.sapien_env import BaseEnv

from . import environment
from .errors import ConfigError
from .physx import enable_physx_gpu

__all__ = ["check_range", "check_pair", "check_flag", "check_choice", "check_size", "check_render_mode",
           "check_splat_look", "check_sim_backend", "check_action", "check_pad_coupling", "is_real", "is_integer"]


def check_range(task: str, name: str, value, low: float, high: float, unit: str = "") -> None:
    """``ConfigError`` ``"<task>: <name>=<value> must be a number in [low, high] unit"`` unless
    ``value`` is a real number (not a bool) with ``low <= value <= high`` (NaN is refused)."""
    if not is_real(value) or not low <= value <= high:
        raise ConfigError(f"{task}: {name}={value!r} must be a number in [{low:g}, {high:g}] {unit}".rstrip())


def check_pair(task: str, name: str, value, low: float, high: float, unit: str = "") -> tuple[float, float]:
    """``value`` as ``(lo, hi)`` floats, or a ``ConfigError`` naming ``name`` unless it is two real
    numbers with ``low <= lo <= hi <= high``."""
    try:
        pair = tuple(value)
    except TypeError:
        pair = ()
    if len(pair) != 2 or not all(is_real(v) for v in pair) or not low <= pair[0] <= pair[1] <= high:
        raise ConfigError(f"{task}: {name}={value!r} must be two numbers (lo, hi) with {low:g} <= lo <= hi <= "
                          f"{high:g} {unit}".rstrip())
    return float(pair[0]), float(pair[1])


def check_flag(task: str, name: str, value) -> None:
    """``ConfigError`` naming ``name`` unless ``value`` is a bool (``bool("no")`` would be True)."""
    if not isinstance(value, (bool, np.bool_)):
        raise ConfigError(f"{task}: {name}={value!r} must be True or False")


def check_choice(task: str, name: str, value, choices) -> None:
    """``ConfigError`` naming ``name`` and the choices unless ``value`` is one of them."""
    if not isinstance(value, str) or value not in choices:
        raise ConfigError(f"{task}: {name}={value!r} must be one of {', '.join(repr(c) for c in choices)}")


def check_size(task: str, name: str, value) -> None:
    """``ConfigError`` naming ``name`` unless ``value`` is (width, height), two integers in [1, 8192] pixels."""
    try:
        wh = tuple(value)
    except TypeError:
        wh = ()
    if len(wh) != 2 or not all(isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))
                               and 1 <= v <= 8192 for v in wh):
        raise ConfigError(f"{task}: {name}={value!r} must be (width, height), two integers in [1, 8192] pixels")


def is_real(value) -> bool:
    """Whether ``value`` is a real number (Python or NumPy), a bool not counting as one."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def is_integer(dtype: torch.dtype) -> bool:
    """Whether ``dtype`` is a torch integer dtype (signed or unsigned; not bool)."""
    return not dtype.is_floating_point and not dtype.is_complex and dtype != torch.bool


def check_render_mode(task: str, render_mode) -> None:
    """``ConfigError`` for a render mode ManiSkill does not know, and for ``"human"`` (SAPIEN's
    viewer window) on a Linux machine without a display (neither ``DISPLAY`` nor
    ``WAYLAND_DISPLAY`` set), where SAPIEN fails deep inside ``gym.make``."""
    if render_mode is None:
        return
    modes = BaseEnv.SUPPORTED_RENDER_MODES
    if render_mode not in modes:
        raise ConfigError(f"{task}: render_mode={render_mode!r} must be None or one of "
                          f"{', '.join(repr(m) for m in modes)}")
    if render_mode == "human" and sys.platform.startswith("linux") and not (
            environment.read("DISPLAY") or environment.read("WAYLAND_DISPLAY")):
        raise ConfigError(f"{task}: render_mode='human' opens SAPIEN's viewer window, and this machine has no "
                          "display (DISPLAY and WAYLAND_DISPLAY are unset); use render_mode='rgb_array', which "
                          "draws without a window (env.render() returns the frames, [B, H, W, 3] uint8)")


def check_splat_look(task: str, splat_background, splat_lighting) -> None:
    """``ConfigError`` naming ``splat_background`` or ``splat_lighting`` unless they are what
    :class:`~gausstac_maniskill.tasks.base.GaussTacEnv` documents (checked for
    ``camera="sapien"`` too)."""
    from .splat.lighting import Lighting

    if not isinstance(splat_lighting, Lighting) and not (isinstance(splat_lighting, str)
                                                         and splat_lighting in ("scene", "baked")):
        raise ConfigError(f"{task}: splat_lighting={splat_lighting!r} must be 'scene', 'baked' or a "
                          "gausstac_maniskill.splat.lighting.Lighting")
    if splat_background is None or (isinstance(splat_background, str) and splat_background == "sapien"):
        return
    try:
        rgb = np.asarray(splat_background, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        rgb = np.zeros(0)
    if isinstance(splat_background, str) or rgb.shape != (3,) or not np.all(np.isfinite(rgb)) \
            or rgb.min() < 0 or rgb.max() > 1:
        raise ConfigError(f"{task}: splat_background={splat_background!r} must be None, 'sapien' or an RGB "
                          "triple in [0, 1]")


def check_optical(task: str, optical, width) -> dict:
    """The kwarg ``optical`` as ``{pad or None (every pad): preset}`` (each preset read, so an
    unknown name or a broken calibration folder fails here, named); ``ConfigError`` naming
    ``optical`` or ``optical_width`` otherwise. The pads' names are checked against the hand
    once it is built."""
    if isinstance(width, bool) or not isinstance(width, (int, np.integer)) or not 8 <= width <= 4096:
        raise ConfigError(f"{task}: optical_width={width!r} must be an integer number of pixels in 8..4096")
    if optical is None:
        return {}
    from .optical import preset

    chosen = {str(k): v for k, v in optical.items()} if isinstance(optical, dict) else {None: optical}
    for pad, name in chosen.items():
        why = "" if isinstance(name, (str, os.PathLike)) else f"{name!r} is not a name"
        if not why:
            try:
                preset(name)
            except ConfigError as e:
                why = str(e)
        if why:
            raise ConfigError(f"{task}: optical={optical!r} must be a preset name ('gelsight', 'gelsight_mini') or a "
                              f"calibration folder, or {{pad: preset}}: {why}")
    return chosen


def check_sim_backend(num_envs, sim_backend) -> None:
    """``ConfigError`` for what ManiSkill or SAPIEN would refuse with a bare error: ``num_envs
    > 1`` where ManiSkill simulates on the CPU (it runs one env per process there, and says
    only "failed to find device cuda"), a GPU backend without CUDA, and a GPU backend whose
    PhysX GPU library SAPIEN cannot fetch (a ``requests`` ConnectionError from deep inside)."""
    if not isinstance(num_envs, int) or isinstance(num_envs, bool) or num_envs < 1:
        raise ConfigError(f"num_envs={num_envs!r} must be a positive integer")
    name = str(sim_backend).split(":")[0]  # "physx_cuda:1" names a device
    cuda = torch.cuda.is_available()
    on_cpu = name in ("physx_cpu", "cpu") or (name == "auto" and (num_envs == 1 or not cuda))
    if num_envs > 1 and on_cpu:
        raise ConfigError(
            f"num_envs={num_envs} with sim_backend={sim_backend!r}: ManiSkill simulates several envs in one "
            "process only on an NVIDIA GPU (sim_backend='physx_cuda'); on the CPU it runs one env per process. "
            "Use gymnasium.vector.AsyncVectorEnv over gym.make(..., num_envs=1), or, to record demonstrations, "
            "`python -m gausstac_maniskill.collect <env_id> --num-procs N` (add --ray [ADDRESS] to spread the "
            "workers over a Ray cluster)")
    if on_cpu or name not in ("physx_cuda", "cuda", "gpu", "auto"):
        return  # ManiSkill names a backend it does not know itself
    if not cuda:
        raise ConfigError(f"sim_backend={sim_backend!r} needs an NVIDIA GPU with CUDA, and torch sees none here "
                          "(torch.cuda.is_available() is False); use sim_backend='physx_cpu' with num_envs=1")
    enable_physx_gpu(sim_backend)


def check_action(task: str, action, single_shape, num_envs: int, control_mode, device):
    """``action`` as a float32 tensor on ``device``, or a ``ConfigError`` naming what is wrong
    (ManiSkill's own answers are a bare ``AssertionError`` for a wrong shape and a NaN
    complaint for an integer array). Accepted: real numbers (int and float dtypes; integers
    cast to float32) of shape ``single_shape`` (``[A]``, the action size of ``control_mode``)
    or ``[num_envs, A]``, all finite; ``single_shape=None`` accepts any shape. ``None`` and
    dict actions pass unchanged."""
    if action is None or isinstance(action, dict):
        return action
    try:
        a = action if isinstance(action, torch.Tensor) else torch.as_tensor(np.asarray(action))
    except (TypeError, ValueError, RuntimeError) as err:
        raise ConfigError(f"{task}: action of type {type(action).__name__} is not an array of numbers "
                          f"({err}); nothing was stepped") from err
    if a.dtype == torch.bool or a.is_complex() or not (a.is_floating_point() or is_integer(a.dtype)):
        raise ConfigError(f"{task}: action of dtype {a.dtype} (shape {tuple(a.shape)}) is not an array of real "
                          "numbers; use float32 (integer arrays are cast to float32); nothing was stepped")
    single = single_shape
    if single is not None:
        single = tuple(single)
        batched = (num_envs, *single)
        if tuple(a.shape) not in (single, batched):
            raise ConfigError(f"{task}: action of shape {tuple(a.shape)}; control_mode {control_mode!r} "
                              f"expects shape {single} or {batched} (num_envs={num_envs}); "
                              "nothing was stepped")
    a = a.to(device=device, dtype=torch.float32)
    if not torch.isfinite(a).all():
        bad = torch.nonzero(~torch.isfinite(a)).tolist()
        raise ConfigError(f"{task}: action contains NaN or inf at {bad[:8]} (shape {list(a.shape)}); "
                          "nothing was stepped")
    return a


def check_pad_coupling(coupling, gpu_sim: bool, enable_tgs: bool, sim_freq, min_freq: float,
                       stacklevel: int = 2) -> None:
    """After ManiSkill's set-up, the pads' reaction coupling (``None``, ``"implicit"`` or
    ``"explicit"``) against the simulation: ``ConfigError`` for any coupling on the GPU sim and
    for ``"implicit"`` with PhysX's TGS solver; a ``UserWarning`` (attributed as
    ``warnings.warn(..., stacklevel=stacklevel)`` in the caller would be) for ``"explicit"``
    below ``min_freq`` [Hz], the SAPIEN rate it was measured stable from."""
    if coupling is not None and gpu_sim:
        raise ConfigError("pad_reaction=True needs sim_backend='physx_cpu': the reaction is applied per "
                          "rigid body, which the GPU simulation does not offer yet")
    if coupling == "implicit" and enable_tgs:
        raise ConfigError("pad_reaction=True needs PhysX's PGS solver (sim_config=dict(scene_config=dict("
                          "enable_tgs=False)), the default with pad_reaction): TGS does not hold the contact "
                          "springs on two-way objects (see tasks/contact_spring.py)")
    if coupling == "explicit" and sim_freq < min_freq:
        warnings.warn(f"pad_reaction='explicit' at sim_freq={sim_freq} Hz: the explicit pad-link coupling was "
                      f"measured stable from {min_freq} Hz on a hand closed hard on an object; "
                      "below, a hard press can fling a finger (pass sim_config=dict(sim_freq=...))",
                      UserWarning, stacklevel=stacklevel + 1)
