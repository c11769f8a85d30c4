"""``GaussTac-GraspSqueezeSponge-v1``: pinch a free foam sponge between the thumb and index
pads, lift it and squeeze it to a target compression.

The sponge is MPM particles only (SAPIEN does not know it): a free elastic block of
``sponge_size`` resting on the ground, which the MPM sees as a half-space with the
sponge's ``sponge_friction``. The pads hold it through the MPM grid (Coulomb friction
``SolverSettings.soft_friction`` between the pads and the sponge), and the sponge pushes
back on the fingers through their joint drives (``pad_reaction=True``, the default). The
splat camera draws it with its Gaussians deformed by the MPM.

Compression: one minus the sponge's width across the pinch, measured between its
particles within ``probe_radius`` of the line joining the thumb's and the index pad's
apexes, over the same width at rest. Success: the sponge's centre of mass is
``lift_height`` above rest, the thumb and the index or middle pad touch it, and the
compression is within ``tolerance`` of the target (drawn in ``compression_range``), for
``hold_time`` without a break.
"""
from __future__ import annotations

import numpy as np
import torch
from mani_skill.utils import common
from mani_skill.utils.registration import register_env

from ..config import MODELS, Material
from ..errors import ConfigError
from ..geometry import HalfSpace, box_particles
from ..task_checks import check_choice, check_pair
from .pinch_grasp import PinchGraspEnv

__all__ = ["GraspSqueezeSpongeEnv"]


@register_env("GaussTac-GraspSqueezeSponge-v1", max_episode_steps=80)
class GraspSqueezeSpongeEnv(PinchGraspEnv):
    """Grasp the sponge, lift it and squeeze it to a target compression.

    Args:
        sponge_E: Young's modulus [Pa] (kitchen sponge: 10–100 kPa).
        sponge_nu: Poisson's ratio (foams: 0–0.3).
        sponge_density: density [kg/m^3] (foams: 20–100).
        sponge_model: ``"neo_hookean"`` (elastic), ``"fixed_corotated"`` or ``"foam"``
            (elastoplastic, keeps a dent).
        sponge_size: full extents [m] (x, y across the pinch, z up), each in [10, 40] mm.
        sponge_friction: Coulomb friction of the sponge on the ground.
        compression_range: target compression range (fraction of the width across the pinch).
        tolerance: the compression counts when within this of the target.
        **kwargs: ``lift_height`` (default 3 cm here), ``hold_time`` (0.5 s),
            ``grasp_force``, ``approach_height``, ``xy_range``, ``pad_reaction`` (see
            :class:`~gausstac_maniskill.tasks.pinch_grasp.PinchGraspEnv`) and
            :class:`~gausstac_maniskill.tasks.base.GaussTacEnv`'s arguments.
    """

    #: radius [m] around the line between the pad apexes within which the width is measured
    probe_radius = 4.0e-3

    def __init__(self, *args, sponge_E: float = 1.0e4, sponge_nu: float = 0.2, sponge_density: float = 100.0,
                 sponge_model: str = "neo_hookean", sponge_size=(0.024, 0.02, 0.03), sponge_friction: float = 1.0,
                 compression_range=(0.15, 0.3), tolerance: float = 0.05, lift_height: float = 0.03,
                 hold_time: float = 0.5, **kwargs):
        self.check_range("sponge_E", sponge_E, 1.0e3, 1.0e6, "Pa")
        self.check_range("sponge_nu", sponge_nu, 0.0, 0.45, "")
        self.check_range("sponge_density", sponge_density, 10.0, 1000.0, "kg/m^3")
        check_choice(self._env_id(), "sponge_model", sponge_model, MODELS)
        size = self._triple("sponge_size", sponge_size, 3)
        for i, v in enumerate(size):
            self.check_range(f"sponge_size[{i}]", v, 0.01, 0.04, "m")
        self.check_range("sponge_friction", sponge_friction, 0.0, 3.0, "")
        lo, hi = check_pair(self._env_id(), "compression_range", compression_range, 0.0, 0.6)
        self.check_range("tolerance", tolerance, 1.0e-3, 0.5, "")
        self.sponge_material = Material(E=sponge_E, nu=sponge_nu, density=sponge_density, model=sponge_model)
        self.sponge_size = tuple(float(v) for v in size)
        self.sponge_friction = float(sponge_friction)
        self.compression_range, self.tolerance = (float(lo), float(hi)), float(tolerance)
        super().__init__(*args, lift_height=lift_height, hold_time=hold_time, **kwargs)

    @classmethod
    def _triple(cls, name: str, value, n: int) -> tuple:
        """``value`` as a tuple of ``n`` entries, or a ``ConfigError`` naming ``name``."""
        try:
            out = tuple(value)
        except TypeError:
            out = ()
        if len(out) != n:
            raise ConfigError(f"{cls._env_id()}: {name}={value!r} must be {n} numbers")
        return out

    # ------------------------------------------------------------------ scene
    def _load_scene(self, options: dict):
        super()._load_scene(options)
        self.add_mpm_rigid("table", self.ground, HalfSpace(friction=self.sponge_friction))
        self.add_mpm_soft("sponge", self._sponge_particles, self.sponge_material)
        B = self.num_envs
        self.sponge_origin = np.zeros((B, 3))  # where each env's sponge centre was drawn [m]
        self.target_compression = torch.full((B,), float(np.mean(self.compression_range)))
        #: the sponge's width [m] across the pinch at rest, measured as :meth:`compression` does
        self.rest_width = _width_along(self._rest_particles(), np.zeros(3), np.array([0.0, 1.0, 0.0]),
                                       self.probe_radius)

    def _rest_particles(self) -> np.ndarray:
        """[N, 3] the sponge's particles at rest, about its centre [m]."""
        half = np.asarray(self.sponge_size) / 2
        return box_particles(-half, half, self.mpm_settings.particle_spacing)

    def _sponge_particles(self, b: int):
        """World particles of env ``b``'s sponge at rest (free: no kinematic particles)."""
        return self._rest_particles() + self.sponge_origin[b], None, None

    @property
    def object_mass(self) -> float:
        return float(np.prod(self.sponge_size) * self.sponge_material.density)

    @property
    def object_friction(self) -> float:
        """The pads' grid friction with soft objects (``SolverSettings.soft_friction``)."""
        return self.mpm_settings.soft_friction

    @property
    def pinch_half_width(self) -> float:
        return self.sponge_size[1] / 2

    @property
    def object_rest_height(self) -> float:
        return self.sponge_size[2] / 2

    def sponge_positions(self, b: int) -> np.ndarray:
        """[N, 3] world positions [m] of env ``b``'s sponge particles."""
        self._ensure_cosims()
        return self.cosims[b].object_positions("sponge")

    def object_centre(self) -> torch.Tensor:
        """[B, 3] the sponge's centre of mass [m] (its particles' mean: equal masses)."""
        c = np.stack([self.sponge_positions(b).mean(0) for b in range(self.num_envs)])
        return torch.as_tensor(c, dtype=torch.float32, device=self.device)

    def _place_object(self, env_idx: torch.Tensor, centre: np.ndarray) -> None:
        self.sponge_origin[common.to_numpy(env_idx)] = centre  # the co-simulators are rebuilt after a reset

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        super()._initialize_episode(env_idx, options)
        rng = self._batched_episode_rng[common.to_numpy(env_idx)]
        self.target_compression[env_idx.cpu()] = torch.as_tensor(
            rng.uniform(*self.compression_range), dtype=torch.float32).reshape(len(env_idx))

    def touch_force(self, pad: str) -> torch.Tensor:
        """[B] normal force [N] the sponge exerted on ``pad`` in the last MPM step: the grid
        contact force between the two velocity fields that reached the pad's link
        (:meth:`~gausstac_maniskill.cosim.GaussTacSim.link_contacts`), along the pad's
        inward normal. The table and other pads on the same link are not counted (Allegro:
        one pad per link)."""
        self._ensure_cosims()
        link = self.pad_geometry(pad).spec.link
        inward = -self.pad_frame(pad)[:, :3, 2].numpy()
        out = [float(sim.link_contacts(link).get(None, np.zeros(7))[:3] @ inward[b]) for b, sim in enumerate(self.cosims)]
        return torch.as_tensor(out, dtype=torch.float32, device=self.device)

    # ------------------------------------------------------------------ task
    def compression(self) -> torch.Tensor:
        """[B] 1 - (sponge width between the pads) / (the same width at rest): the width is
        the extent, along the line joining the thumb's and the index pad's apexes, of the
        sponge particles within ``probe_radius`` of that line (0 when none is)."""
        thumb = self.pad_frame("thumb")[:, :3, 3].numpy()
        index = self.pad_frame("index")[:, :3, 3].numpy()
        out = np.zeros(self.num_envs)
        for b in range(self.num_envs):
            u = index[b] - thumb[b]
            u /= max(np.linalg.norm(u), 1e-9)
            width = _width_along(self.sponge_positions(b), thumb[b], u, self.probe_radius)
            out[b] = 0.0 if width is None else 1.0 - width / self.rest_width
        return torch.as_tensor(out, dtype=torch.float32)

    def _hold_condition(self) -> torch.Tensor:
        return (self.compression() - self.target_compression).abs() < self.tolerance

    def evaluate(self):
        c = self.compression()
        return dict(**self._pinch_info(), compression=c.to(self.device),
                    compression_error=(c - self.target_compression).abs().to(self.device))

    def _get_task_state(self):
        return {**super()._get_task_state(), "target_compression": self.target_compression.clone(),
                "sponge_origin": torch.as_tensor(self.sponge_origin)}

    def _set_task_state(self, state, env_idx):
        super()._set_task_state(state, env_idx)
        self.target_compression[env_idx] = state["target_compression"].to(self.target_compression)
        self.sponge_origin[common.to_numpy(env_idx)] = state["sponge_origin"].double().numpy()

    def _get_obs_extra(self, info: dict):
        return dict(sponge_centre=self.object_centre(), pinch_point=self.pinch_point(),
                    compression=info["compression"][:, None],
                    target_compression=self.target_compression[:, None].to(self.device),
                    hold_time=info["hold_time"][:, None])

    def compute_dense_reward(self, obs, action, info):
        """reach + grasp + 2 lift + 2 hold (as the cube's) + 2 squeeze (1 - tanh(10 |c - c*|)
        while grasped) + 3 on success."""
        squeeze = (1 - torch.tanh(10.0 * info["compression_error"])) * info["grasped"].float()
        return self._pinch_reward(info) + 2 * squeeze + 3 * info["success"].float()

    def compute_normalized_dense_reward(self, obs, action, info):
        return self.compute_dense_reward(obs, action, info) / 11.0


def _width_along(x: np.ndarray, origin: np.ndarray, u: np.ndarray, radius: float) -> float | None:
    """Extent [m] along unit ``u`` of the points ``x`` within ``radius`` of the line
    ``origin + s u``; None when no point is."""
    s = (x - origin) @ u
    r = np.linalg.norm(x - origin - s[:, None] * u, axis=1)
    near = s[r < radius]
    return float(near.max() - near.min()) if near.size else None
