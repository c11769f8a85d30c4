"""Tactile maps as an extra observation for ManiSkill's imitation-learning baselines.

GaussTac envs return ``obs["tactile"] = {pad: {"depth" [B, H, W] m, "shear" [B, H, W, 2] m,
"force" [B, H, W] N}}`` (H × W the pad's taxels: 16 × 16 on the Allegro pads); a recorded ``.h5`` holds the same under ``obs/tactile/<pad>/...`` with a
time axis for the env axis. ManiSkill's flatteners refuse arrays of more than 2 dims, so one
:class:`TactileLayout` turns the maps into a vector the same way for the live env
(:class:`TactileObsWrapper`) and the recorded data (:func:`tactile_state_obs_extractor`,
:func:`load_demos`, :func:`flatten_file`): a policy sees at evaluation what it was trained on.
Vector: pads in sorted name order, per pad the ``fields`` in order, each map average-pooled by
``pool``, times ``scale[field]`` (default m -> mm for depth and shear), flattened row-major (shear:
x, y last); 4 Allegro pads of 16 × 16 give 4096 entries at pool 1, 256 at pool 4. Image:
``[..., H/pool, W/pool, C]``, channels last, C = pads x channels in the same order. Example::

    env = gym.make("GaussTac-PressCube-v1", obs_mode="rgb", control_mode="pd_joint_delta_pos")
    env = FlattenRGBDObservationWrapper(TactileObsWrapper(env))  # state [B, 89 + 4096], rgb [B, 128, 128, 3]
"""
from __future__ import annotations

import argparse
import copy
import sys
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import gymnasium as gym
import numpy as np
import torch
from mani_skill.trajectory.dataset import load_h5_data

from .errors import ConfigError

__all__ = ["TACTILE_FIELDS", "DEFAULT_SCALE", "TactileLayout", "TactileObsWrapper", "tactile_state_obs_extractor",
           "load_demos", "recorded_env_kwargs", "flatten_file", "main"]

#: Tactile fields in the observation and their channel counts.
TACTILE_FIELDS = {"depth": 1, "shear": 2, "force": 1}
#: Default factors applied to the fields: depth and shear m -> mm, force in N.
DEFAULT_SCALE = {"depth": 1.0e3, "shear": 1.0e3, "force": 1.0}


def _is_torch(x) -> bool:
    return isinstance(x, torch.Tensor)


@dataclass
class TactileLayout:
    """How the tactile maps become a vector or an image stack (see the module docstring).

    Args:
        fields: which maps, in this order (subset of depth, shear, force).
        pads: pad ids to keep (default: all, sorted by name).
        scale: factor per field (default :data:`DEFAULT_SCALE`).
        pool: average-pool the maps by this factor (must divide H and W).
    """

    fields: Sequence[str] = ("depth", "shear", "force")
    pads: Sequence[str] | None = None
    scale: Mapping[str, float] | None = None
    pool: int = 1
    _scale: dict = field(init=False, repr=False)

    def __post_init__(self):
        self.fields = tuple(self.fields)
        bad = [f for f in self.fields if f not in TACTILE_FIELDS]
        if bad or not self.fields or len(set(self.fields)) != len(self.fields):
            raise ConfigError(f"fields={self.fields!r}: choose distinct names among {sorted(TACTILE_FIELDS)}")
        if not isinstance(self.pool, (int, np.integer)) or self.pool < 1:
            raise ConfigError(f"pool={self.pool!r} must be an integer >= 1")
        self._scale = {**DEFAULT_SCALE, **dict(self.scale or {})}
        if self.pads is not None:
            self.pads = tuple(self.pads)

    # ------------------------------------------------------------------ helpers
    def pad_ids(self, tactile: Mapping) -> list[str]:
        if self.pads is None:
            return sorted(tactile)
        missing = [p for p in self.pads if p not in tactile]
        if missing:
            raise ConfigError(f"tactile observation has no pad(s) {missing}; it has {sorted(tactile)}")
        return list(self.pads)

    def _maps(self, tactile: Mapping):
        """Per (pad, field): array [..., h, w, c], scaled and pooled."""
        out = []
        for pad in self.pad_ids(tactile):
            for f in self.fields:
                if f not in tactile[pad]:
                    raise ConfigError(f"tactile[{pad!r}] has no {f!r} map; it has {sorted(tactile[pad])}")
                m = tactile[pad][f]
                m = m if _is_torch(m) else np.asarray(m)
                if TACTILE_FIELDS[f] == 1:
                    m = m[..., None]
                m = m * self._scale[f]
                if self.pool > 1:
                    h, w = m.shape[-3], m.shape[-2]
                    k = self.pool
                    if h % k or w % k:
                        raise ConfigError(f"pool={k} does not divide the {h}x{w} {f} map of pad {pad!r}")
                    # a fixed order of elementwise adds: numpy (data) and torch (live env) agree to the bit
                    acc = None
                    for i in range(k):
                        for j in range(k):
                            part = m[..., i::k, j::k, :]
                            acc = part if acc is None else acc + part
                    m = acc / (k * k)
                out.append(m)
        return out

    def vector(self, tactile: Mapping):
        """``{pad: {field: [..., H, W(, 2)]}}`` -> ``[..., D]`` float32 (torch or numpy, as given)."""
        maps = self._maps(tactile)
        if _is_torch(maps[0]):
            return torch.cat([m.reshape(*m.shape[:-3], -1) for m in maps], dim=-1).to(torch.float32)
        return np.concatenate([m.reshape(*m.shape[:-3], -1) for m in maps], axis=-1).astype(np.float32)

    def image(self, tactile: Mapping):
        """``{pad: {field: [..., H, W(, 2)]}}`` -> ``[..., H/pool, W/pool, C]`` float32."""
        maps = self._maps(tactile)
        if _is_torch(maps[0]):
            return torch.cat(maps, dim=-1).to(torch.float32)
        return np.concatenate(maps, axis=-1).astype(np.float32)

    def size(self, num_pads: int, rows: int = 16, cols: int = 16) -> int:
        """Length of :meth:`vector` for ``num_pads`` pads of ``rows x cols`` taxels."""
        ch = sum(TACTILE_FIELDS[f] for f in self.fields)
        return num_pads * (rows // self.pool) * (cols // self.pool) * ch


class TactileObsWrapper(gym.ObservationWrapper):
    """Replace ``obs["tactile"]`` (nested maps) by a ``[B, D]`` vector (``layout="vector"``)
    or a ``[B, h, w, C]`` image stack (``layout="image"``); the rest of the observation is
    untouched. Put it before ManiSkill's ``FlattenRGBDObservationWrapper`` (the tactile
    vector then joins ``"state"`` after agent and extra). ``flatten=True`` (vector layout)
    returns one ``[B, S + D]`` tensor instead: agent, extra (and any other non-camera
    entries) then tactile, flattened like ManiSkill's ``flatten_state_dict`` — the obs of
    ManiSkill's state-based baselines, for obs_mode ``state_dict`` (ManiSkill's
    ``FlattenObservationWrapper`` fails on nested observation dicts). ManiSkill's wrappers
    read ``base_env._init_raw_obs``, which this one updates as theirs do. Keyword arguments other
    than ``layout``, ``key`` and ``flatten`` are those of :class:`TactileLayout`; ``key``
    renames the entry (default ``"tactile"``).
    """

    def __init__(self, env, layout: str = "vector", key: str = "tactile", flatten: bool = False,
                 **layout_kwargs) -> None:
        super().__init__(env)
        if layout not in ("vector", "image"):
            raise ConfigError(f"layout={layout!r} must be 'vector' or 'image'")
        if flatten and layout != "vector":
            raise ConfigError("flatten=True needs layout='vector'")
        self.layout_kind = layout
        self.key = key
        self.flatten = bool(flatten)
        self.layout = TactileLayout(**layout_kwargs)
        raw = self.base_env._init_raw_obs
        if not isinstance(raw, dict) or "tactile" not in raw:
            raise ConfigError("TactileObsWrapper needs a GaussTac env with a dict observation holding 'tactile' "
                              f"(obs_mode={self.base_env.obs_mode!r} gives "
                              f"{sorted(raw) if isinstance(raw, dict) else type(raw).__name__}); use obs_mode "
                              "state_dict, rgb, rgbd or sensor_data")
        self.base_env.update_obs_space(self.observation(copy.copy(raw)))

    @property
    def base_env(self):
        return self.env.unwrapped

    def observation(self, observation: dict) -> dict:
        obs = dict(observation)
        tactile = obs.pop("tactile")
        obs[self.key] = self.layout.vector(tactile) if self.layout_kind == "vector" else self.layout.image(tactile)
        if self.flatten:
            from mani_skill.utils import common

            rest = {k: v for k, v in obs.items() if k not in ("sensor_data", "sensor_param")}
            return common.flatten_state_dict(rest, use_torch=True, device=self.base_env.device)
        return obs


def tactile_state_obs_extractor(**layout_kwargs):
    """``obs -> [agent values..., extra values..., tactile vector]``, a drop-in for
    ``build_state_obs_extractor(env_id)`` of ManiSkill's diffusion-policy baseline
    (``diffusion_policy/utils.py``): on the recorded obs (``[T+1, ...]`` arrays) it gives the
    ``state`` that :class:`TactileObsWrapper` + ``FlattenRGBDObservationWrapper`` give live."""
    layout = TactileLayout(**layout_kwargs)

    def extract(obs):
        return list(obs["agent"].values()) + list(obs["extra"].values()) + [layout.vector(obs["tactile"])]

    return extract


def _flat(d: Mapping, n: int) -> np.ndarray:
    """Like ``mani_skill.utils.common.flatten_state_dict`` on [n, ...] leaves."""
    parts = []
    for v in d.values():
        if isinstance(v, Mapping):
            parts.append(_flat(v, n))
        else:
            v = np.asarray(v)
            if v.ndim > 2:
                raise ConfigError(f"cannot flatten an observation leaf of shape {v.shape} (more than [T, D])")
            parts.append(v.reshape(n, -1).astype(np.float32))
    return np.concatenate(parts, axis=1) if parts else np.zeros((n, 0), np.float32)


#: env kwargs of a recording that a training script sets itself (or that belong to the recorder)
_SET_BY_THE_SCRIPT = ("obs_mode", "control_mode", "sim_backend", "render_mode", "num_envs", "reward_mode")


def recorded_env_kwargs(path: str) -> dict:
    """The task's own keyword arguments a recording was made with (``mpm_dx``, ``pad_solver``,
    ``--env-kwarg`` values, ...), read from the ``.json`` beside the ``.h5`` at ``path``, without
    the ones a training script passes itself (obs and control mode, backend, render mode, env
    count): pass them to the evaluation env, ``gym.make(env_id, **recorded_env_kwargs(path), ...)``,
    so that it steps the physics the demos were recorded with.

    Raises:
        ConfigError: there is no ``.json`` beside ``path``, or it has no ``env_info.env_kwargs``.
    """
    import json
    from pathlib import Path

    meta = Path(path).with_suffix(".json")
    if not meta.is_file():
        raise ConfigError(f"recorded_env_kwargs: {meta} not found (ManiSkill writes it beside the .h5 {path})")
    info = json.loads(meta.read_text()).get("env_info", {})
    if "env_kwargs" not in info:
        raise ConfigError(f"recorded_env_kwargs: {meta} has no env_info.env_kwargs (not a ManiSkill trajectory json)")
    return {k: v for k, v in info["env_kwargs"].items() if k not in _SET_BY_THE_SCRIPT}


def load_demos(path: str, num_traj: int | None = None, *, include_last: bool = False, rgb: bool = True,
               **layout_kwargs) -> dict:
    """Load a recorded GaussTac ``.h5`` into flat arrays for behaviour cloning.

    Returns a dict of numpy arrays over all N kept steps (trajectories in id order; the
    last observation of each trajectory, which has no action, is dropped unless
    ``include_last``; then ``actions`` is absent):

    * ``state`` [N, S + D] float32: ``obs/agent`` then ``obs/extra`` flattened then the tactile
      vector — what :class:`TactileObsWrapper` + ``FlattenRGBDObservationWrapper`` (or
      ``TactileObsWrapper(flatten=True)``) return live;
    * ``tactile`` [N, D] float32: the tactile vector alone (:class:`TactileLayout`);
    * ``rgb`` [N, H, W, 3 x cameras] uint8 (rgb obs mode, ``rgb=True``);
    * ``optical/<pad>`` [N, H, W, 3] uint8 and ``markers/<pad>`` [N, M, 2] float32 [px]: the
      optical image and markers of each pad recorded with an optical sensor (``optical=``);
    * ``actions`` [N, A] float32; ``episode`` [N] int (trajectory index), ``t`` [N] int (step).
    """
    import h5py

    layout = TactileLayout(**layout_kwargs)
    out: dict[str, list] = {"state": [], "tactile": [], "rgb": [], "actions": [], "episode": [], "t": []}
    optical: dict[str, list] = {}
    with h5py.File(path, "r") as f:
        names = sorted((k for k in f if k.startswith("traj_")), key=lambda k: int(k.split("_")[1]))
        if num_traj is not None:
            names = names[:num_traj]
        if not names:
            raise ConfigError(f"{path} holds no traj_* groups")
        for i, name in enumerate(names):
            g = f[name]
            if "obs" not in g or not hasattr(g["obs"], "keys") or "tactile" not in g["obs"]:
                raise ConfigError(f"{path}:{name} has no obs/tactile group (recorded with obs_mode 'state'? "
                                  "record with rgb or state_dict)")
            obs = g["obs"]
            n = obs["tactile"][next(iter(obs["tactile"]))]["depth"].shape[0]
            keep = n if include_last else n - 1
            tac = layout.vector(load_h5_data(obs["tactile"]))[:keep]
            base = _flat({k: load_h5_data(obs[k]) for k in ("agent", "extra") if k in obs}, n)[:keep]
            out["state"].append(np.concatenate([base, tac], axis=1))
            out["tactile"].append(tac)
            if rgb and "sensor_data" in obs:
                cams = [obs["sensor_data"][c]["rgb"][:keep] for c in obs["sensor_data"]
                        if "rgb" in obs["sensor_data"][c]]
                if cams:
                    out["rgb"].append(np.concatenate(cams, axis=-1))
            for pad in obs["tactile"]:
                for key in ("rgb", "markers"):
                    if key in obs["tactile"][pad]:
                        name = f"{'optical' if key == 'rgb' else key}/{pad}"
                        optical.setdefault(name, []).append(obs["tactile"][pad][key][:keep])
            if not include_last:
                out["actions"].append(g["actions"][()].astype(np.float32))
            out["episode"].append(np.full(keep, i, np.int64))
            out["t"].append(np.arange(keep, dtype=np.int64))
    out.update(optical)
    return {k: np.concatenate(v, axis=0) for k, v in out.items() if v}


def flatten_file(src: str, dst: str, **layout_kwargs) -> dict:
    """Copy a recorded ``.h5`` (+ ``.json``) to ``dst`` with every ``obs`` group replaced by
    the flat float32 ``[T+1, S + D]`` state of :func:`load_demos` (camera images dropped),
    the layout ManiSkill's state-based baselines (``diffusion_policy/train.py``, ``bc/bc.py``)
    read. Evaluate such a policy on ``obs_mode="state_dict"`` wrapped in
    ``TactileObsWrapper(env, flatten=True, **layout_kwargs)``.
    Returns ``{"traj": count, "obs_dim": S + D}``."""
    import os

    import h5py
    from mani_skill.utils.io_utils import dump_json, load_json

    if os.path.abspath(src) == os.path.abspath(dst):
        raise ConfigError("flatten_file: dst must differ from src")
    layout = TactileLayout(**layout_kwargs)
    dim = 0
    with h5py.File(src, "r") as fi, h5py.File(dst, "w") as fo:
        names = [k for k in fi if k.startswith("traj_")]
        for name in names:
            g, h = fi[name], fo.create_group(name, track_order=True)
            for k in g:
                if k != "obs":
                    fi.copy(g[k], h, name=k)
            obs = g["obs"]
            if "tactile" not in obs:
                raise ConfigError(f"{src}:{name} has no obs/tactile group")
            n = obs["tactile"][next(iter(obs["tactile"]))]["depth"].shape[0]
            base = _flat({k: load_h5_data(obs[k]) for k in ("agent", "extra") if k in obs}, n)
            flat = np.concatenate([base, layout.vector(load_h5_data(obs["tactile"]))], axis=1)
            h.create_dataset("obs", data=flat, compression="gzip", shuffle=True)
            dim = flat.shape[1]
    meta = load_json(src.replace(".h5", ".json"))
    meta["env_info"]["env_kwargs"]["obs_mode"] = "state_dict"
    meta["gausstac_obs_layout"] = dict(fields=list(layout.fields), pads=layout.pads, scale=layout._scale,
                                       pool=layout.pool, note="obs = agent + extra + tactile vector")
    dump_json(dst.replace(".h5", ".json"), meta, indent=2)
    return {"traj": len(names), "obs_dim": dim}


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m gausstac_maniskill.obs_wrappers flatten SRC.h5 DST.h5 [--pool 4] [--pads index ...]``"""
    p = argparse.ArgumentParser(prog="python -m gausstac_maniskill.obs_wrappers",
                                description="Write a copy of a recorded file whose obs are flat state+tactile "
                                            "vectors (for ManiSkill's state-based DP/BC baselines).")
    sub = p.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("flatten", help="SRC.h5 -> DST.h5 with obs [T+1, S + D]")
    f.add_argument("src")
    f.add_argument("dst")
    f.add_argument("--pool", type=int, default=1)
    f.add_argument("--pads", nargs="+", default=None)
    f.add_argument("--fields", nargs="+", default=["depth", "shear", "force"])
    args = p.parse_args(argv)
    try:
        info = flatten_file(args.src, args.dst, pool=args.pool, pads=args.pads, fields=args.fields)
    except ConfigError as exc:
        print(f"obs_wrappers: error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.dst}: {info['traj']} trajectories, obs dim {info['obs_dim']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
