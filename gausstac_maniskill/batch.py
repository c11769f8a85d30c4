"""BatchedCosim: B scenes (envs) of soft pads and objects in one MPM world.

Every env is a :class:`~gausstac_maniskill.cosim.GaussTacSim` built into the same
:class:`~gausstac_maniskill.mpm.MPMWorld` as env ``b``: its particles, links and colliders
carry the env index, the grid holds one copy of the active box per env, and a particle
touches only its own env's colliders. All envs advance in the same kernel launches (their
number does not grow with B). Envs sleep and wake per pad, as in a scene alone.

Every env takes the same substeps (the most demanding env's CFL bound) and then steps as
it would alone, to float rounding; with ``SolverSettings(pressure="implicit")`` the envs share
one conjugate-gradient pressure solve, so only to the CG tolerance (untested).

Data flows one way: link poses [B, L, 4, 4] (torch or numpy, world frame, m) →
:meth:`BatchedCosim.step` → pad and object solvers → tactile maps
``{pad: {map: [B, H, W(, 2)]}}``. Each env's state saves and restores on its own
(``scenes[b].flat_state()`` / ``load_flat_state``), in the layout of the same scene alone.
:meth:`BatchedCosim.render` draws every env's splat scene in one rasterizer call (each
camera sees its own env's Gaussians only).
"""
from __future__ import annotations

import functools
from typing import Mapping, Sequence

import numpy as np
import torch

from .config import PadSolverSettings, PadSpec, SolverSettings
from .cosim import GaussTacSim
from .errors import ConfigError
from .mpm import MPMWorld
from .geometry.colliders import Collider
from .render import BatchScene
from .transforms import as_pose_matrices
from .tactile.readout import TactileReadout

__all__ = ["BatchedCosim"]


def _as_batch(poses, name: str) -> np.ndarray:
    """``poses`` ([B, ..., 4, 4] tensor or array) as checked float64 rigid transforms (a copy)."""
    if isinstance(poses, torch.Tensor):
        poses = poses.detach().cpu().double().numpy()
    arr = np.array(poses, np.float64)  # a copy: the scenes keep views of it
    if arr.ndim < 3 or arr.shape[-2:] != (4, 4):
        raise ConfigError(f"{name} must have shape [B, ..., 4, 4], got {list(arr.shape)}")
    return as_pose_matrices(arr, name)


class BatchedCosim:
    """B co-simulated scenes in one MPM world (see the module docstring).

    Args:
        pads: pad descriptions, the same in every env.
        link_names: the L links whose poses :meth:`step` receives (every pad link among them).
        link_poses: [B, L, 4, 4] initial world poses [m] of those links; B is the env count.
        urdf, settings: as :class:`~gausstac_maniskill.cosim.GaussTacSim`.
        pad_settings: how the pads are solved (:class:`~gausstac_maniskill.config.PadSolverSettings`,
            default: its defaults), the same in every env. With equilibrium pads every env solves
            its pads after the world's step, one env after another on the host, with one body
            (factor and compliance) per pad shared by all envs.
    """

    def __init__(self, pads: Sequence[PadSpec], link_names: Sequence[str], link_poses, *,
                 urdf: str | None = None, settings: SolverSettings | None = None,
                 pad_settings: PadSolverSettings | None = None):
        self.link_names = list(link_names)
        P = _as_batch(link_poses, "BatchedCosim link_poses")
        if P.ndim != 4 or P.shape[1] != len(self.link_names):
            raise ConfigError(f"BatchedCosim link_poses must have shape [B, {len(self.link_names)}, 4, 4] "
                              f"(one pose per link of link_names), got {list(P.shape)}")
        self.world = MPMWorld(settings or SolverSettings())
        self.pad_settings = pad_settings or PadSolverSettings()
        self.scenes = [GaussTacSim(pads, self._env_poses(P, b), urdf=urdf, world=self.world, env=b,
                                   pad_settings=self.pad_settings)
                       for b in range(P.shape[0])]
        for scene in self.scenes[1:]:  # one body per pad (its factor and compliance) for every env
            scene.solvers["fem"].share_bodies(self.scenes[0].solvers["fem"])
        self.pad_names = [p.name for p in pads]
        self._readout: tuple | None = None  # (the MPM pads it reads, their TactileReadout)
        self._splat = BatchScene()
        self._soft_key: list | None = None  # the envs' splat scenes that _soft_rows was built for
        self._soft_rows = None
        self._links = None  # (world link count, columns, world rows) of _world_links

    @property
    def num_envs(self) -> int:
        """B, the number of envs."""
        return len(self.scenes)

    def _env_poses(self, P: np.ndarray, b: int) -> dict[str, np.ndarray]:
        return {n: P[b, i] for i, n in enumerate(self.link_names)}

    def _world_links(self) -> tuple[np.ndarray, np.ndarray]:
        """(columns of :attr:`link_names` that the world simulates, [K]; their world link
        indices env by env, [B·K]): what :meth:`advance` sends to the world."""
        if self._links is None or self._links[0] != len(self.world.link_names):
            w = self.world
            cols = [i for i, n in enumerate(self.link_names) if w.has_link(self.scenes[0]._w(n))]
            rows = [w.link_index(s._w(self.link_names[i])) for s in self.scenes for i in cols]
            self._links = (len(w.link_names), np.array(cols, np.int64), np.array(rows, np.int64))
        return self._links[1], self._links[2]

    def add_rigid_object(self, name: str, colliders: Sequence[Collider]) -> None:
        """Rigid object ``name`` in every env: ``colliders[b]`` is env b's (its shape and
        initial pose; the envs' objects may differ)."""
        if len(colliders) != self.num_envs:
            raise ConfigError(f"add_rigid_object({name!r}): {len(colliders)} colliders for {self.num_envs} envs")
        for scene, col in zip(self.scenes, colliders):
            scene.add_rigid_object(name, col)

    def step(self, link_poses, dt: float, object_poses: Mapping[str, object] | None = None) -> dict:
        """Advance every env ``dt`` seconds, its links moving to ``link_poses`` [B, L, 4, 4]
        and its rigid objects to ``object_poses`` (name → [B, 4, 4]); returns :meth:`tactile`."""
        self.advance(link_poses, dt, object_poses)
        return self.tactile()

    def advance(self, link_poses, dt: float, object_poses: Mapping[str, object] | None = None) -> None:
        """:meth:`step` without building the maps (a caller that reads them later, or not at all)."""
        P = _as_batch(link_poses, "BatchedCosim.step link_poses")
        if P.shape[:2] != (self.num_envs, len(self.link_names)):
            raise ConfigError(f"BatchedCosim.step link_poses must have shape [{self.num_envs}, "
                              f"{len(self.link_names)}, 4, 4], got {list(P.shape)}")
        objects = {k: _as_batch(v, f"object_poses[{k!r}]") for k, v in (object_poses or {}).items()}
        for k, v in objects.items():
            if v.shape != (self.num_envs, 4, 4):
                raise ConfigError(f"object_poses[{k!r}] must have shape [{self.num_envs}, 4, 4], got {list(v.shape)}")
        cols, rows = self._world_links()
        self.world.set_link_poses(P[:, cols].reshape(-1, 4, 4), rows)  # every env's links in one call
        for b, scene in enumerate(self.scenes):
            scene.after_link_poses(self._env_poses(P, b), {k: v[b] for k, v in objects.items()})
        self.world.step(dt)
        for scene in self.scenes:
            scene.end_step()

    def tactile(self, device=None) -> dict[str, dict[str, torch.Tensor]]:
        """``{pad: {"depth": [B, H, W] m, "shear": [B, H, W, 2] m, "force": [B, H, W] N,
        "pressure": [B, H, W] Pa}}`` of the last step (float32, on ``device``; the Taichi
        arch's by default). One launch reads every env's pads on the device: only the maps
        are copied (:class:`~gausstac_maniskill.tactile.readout.TactileReadout`)."""
        maps = {}
        mpm = self.scenes[0].solvers["mpm"]
        if len(mpm):  # every env's MPM pads in one launch
            if self._readout is None or self._readout[0] != mpm.names:
                pads = [self.scenes[0].pads[n] for n in mpm.names]
                self._readout = (list(mpm.names), TactileReadout(self.world, pads,
                                                                 [s.solvers["mpm"].slots() for s in self.scenes]))
            maps = self._readout[1].maps(device)
        for kind, solver in self.scenes[0].solvers.items():  # the others env by env, stacked
            if kind == "mpm" or not len(solver):
                continue
            envs = [s.solvers[kind].tactile() for s in self.scenes]  # (computed once per step, whoever reads them)
            for name in solver.names:
                maps[name] = {k: torch.stack([m[name][k] for m in envs]) for k in envs[0][name]}
                if device is not None:
                    maps[name] = {k: v.to(device) for k, v in maps[name].items()}
        return {name: maps[name] for name in self.pad_names}

    def render(self, viewmats, Ks, width: int, height: int, camera_env=None, **kwargs):
        """Render every env's splat scene (:meth:`GaussTacSim.attach_gaussians`) in one
        rasterizer call: camera c ([C, 4, 4] world -> camera ``viewmats``, OpenCV; [C, 3, 3]
        pixel ``Ks``) sees env ``camera_env[c]`` (default: camera b, env b) and nothing of the
        others; an env without Gaussians shows the background. ``kwargs`` as
        :func:`~gausstac_maniskill.splat.rasterize`: ``background`` [C, H, W, 3] or a colour,
        ``background_depth`` [C, H, W] m, ``lighting`` (one, or one per camera). Returns a
        ``RenderOutput`` (rgb [C, H, W, 3], depth [C, H, W] m, alpha [C, H, W]) on the Taichi
        arch's torch device. The particles the soft Gaussians ride on are read on the device, in
        one launch for all envs (:meth:`_soft_frames`)."""
        soft = functools.cache(self._soft_frames)  # read at most once, if some env needs posing
        posed = [s.posed_scene(lambda b=b: soft()[b]) if s.has_gaussians else None
                 for b, s in enumerate(self.scenes)]
        return self._splat.render(posed, viewmats, Ks, width, height, camera_env, **kwargs)

    def _soft_frames(self) -> list:
        """Per env (None without Gaussians), the frames [P'_b, 3, 4] of the particles its soft
        Gaussians ride on, sleeping pads carried by their links (see
        :func:`~gausstac_maniskill.mpm.gather.carried_frames`): one launch for every env's world
        particles, the rows kept on the device while the envs' splat scenes stay the same; pads
        solved at equilibrium from their solution, env by env
        (:meth:`~gausstac_maniskill.render.SceneGaussians.solved_frames`)."""
        from . import backend
        from .mpm.gather import read_particle_frames

        scenes = [s.splat_scene for s in self.scenes]
        key = [sc.framed() if sc is not None else None for sc in scenes]
        if self._soft_key is None or any(a is not b for a, b in zip(key, self._soft_key)):
            rows, carry, sizes = [], [], []
            for b, sc in enumerate(scenes):
                r, c = sc.world_rows() if sc is not None else (np.zeros(0, np.int64), np.zeros(0, np.int32))
                rows.append(r)
                carry.append(c + b * (1 + len(self.pad_names)))  # env b's carries follow env b-1's
                sizes.append(len(r))
            dev = backend.torch_device()
            self._soft_rows = (torch.as_tensor(np.concatenate(rows), dtype=torch.int32, device=dev),
                               torch.as_tensor(np.concatenate(carry), dtype=torch.int32, device=dev),
                               np.cumsum([0] + sizes))
            self._soft_key = key
        rows, carry, starts = self._soft_rows
        carries = np.concatenate([s.pad_carries() for s in self.scenes])
        frames = read_particle_frames(self.world, rows, carry, carries)
        return [None if sc is None else torch.cat([sc.solved_frames(frames.device), frames[starts[b]:starts[b + 1]]])
                for b, sc in enumerate(scenes)]

    def object_wrench(self, name: str) -> np.ndarray:
        """[B, 6] force [N] and torque [N·m] (about its origin) the pads exerted on rigid
        object ``name`` in each env during the last step."""
        return np.stack([np.concatenate(s.object_wrench(name)) for s in self.scenes])

    def link_contacts(self, link: str) -> list[dict]:
        """Per env, :meth:`GaussTacSim.link_contacts` of hand link ``link``."""
        return [s.link_contacts(link) for s in self.scenes]
