"""``GaussTac-SqueezeSponge-v1``: squeeze a soft sponge to a target compression.

A sponge block (MPM particles only: SAPIEN does not know it; the splat camera draws it
with its Gaussians deformed by the MPM) is glued at its back to a fixed holder, its
front face 2–4 mm in front of the index pad. The index fingertip squeezes it against
the holder. Compression = mean indentation of the sponge's front face within
``probe_radius`` of the pad apex, divided by the sponge thickness; success within
``tolerance`` of the target, drawn in [0.15, 0.30]. The sponge's Young's modulus,
Poisson's ratio and model are arguments.
"""
from __future__ import annotations

import numpy as np
import sapien
import torch
from mani_skill.utils.registration import register_env

from ..config import MODELS, Material
from ..geometry import box_particles
from ..task_checks import check_choice, check_pair
from .press_cube import IndexCubeTask

__all__ = ["SqueezeSpongeEnv"]

SPONGE_HALF = (0.012, 0.012)   # m, half width and height of the face
HOLDER_HALF = (0.016, 0.016, 0.003)


@register_env("GaussTac-SqueezeSponge-v1", max_episode_steps=40)
class SqueezeSpongeEnv(IndexCubeTask):
    """Squeeze the sponge with the index fingertip to a target compression.

    Args:
        sponge_E: Young's modulus [Pa], in [1 kPa, 1 MPa] (kitchen sponge: 10–100 kPa).
        sponge_nu: Poisson's ratio, in [0, 0.45] (foams: 0–0.3).
        sponge_density: density [kg/m^3], in [10, 1000].
        sponge_model: ``"neo_hookean"`` (elastic), ``"fixed_corotated"`` or ``"foam"``
            (elastoplastic, keeps a dent).
        sponge_thickness: thickness [m] along the squeeze direction, in [4, 30] mm.
        compression_range: target compression range (lo, hi) (fraction of the thickness),
            0 <= lo <= hi <= 0.6.
        tolerance: success when |compression - target| < tolerance, in [0.001, 0.5].

    Every argument is checked before anything is built: a ``ConfigError`` names it, the
    value given and the range.
    """

    probe_radius = 4.0e-3

    def __init__(self, *args, sponge_E: float = 3.0e4, sponge_nu: float = 0.2, sponge_density: float = 60.0,
                 sponge_model: str = "neo_hookean", sponge_thickness: float = 0.010,
                 compression_range=(0.15, 0.30), tolerance: float = 0.04, **kwargs):
        task = self._env_id()
        self.check_range("sponge_E", sponge_E, 1.0e3, 1.0e6, "Pa")
        self.check_range("sponge_nu", sponge_nu, 0.0, 0.45)
        self.check_range("sponge_density", sponge_density, 10.0, 1000.0, "kg/m^3")
        check_choice(task, "sponge_model", sponge_model, MODELS)
        self.check_range("sponge_thickness", sponge_thickness, 0.004, 0.03, "m")
        self.compression_range = check_pair(task, "compression_range", compression_range, 0.0, 0.6)
        self.check_range("tolerance", tolerance, 1e-3, 0.5)
        self.sponge_material = Material(E=sponge_E, nu=sponge_nu, density=sponge_density, model=sponge_model)
        self.sponge_thickness = float(sponge_thickness)
        self.tolerance = float(tolerance)
        self.block_half = HOLDER_HALF
        super().__init__(*args, **kwargs)

    def _load_block(self):
        b = self.scene.create_actor_builder()
        b.add_box_visual(half_size=HOLDER_HALF, material=sapien.render.RenderMaterial(base_color=[0.3, 0.35, 0.4, 1]))
        b.initial_pose = sapien.Pose(p=[0.09, 0.05, 0.06])
        holder = b.build_kinematic(name="holder")
        self.add_mpm_soft("sponge", self._sponge_particles, self.sponge_material)
        self._sponge_rest = {}
        self.target_compression = torch.full((self.num_envs,), 0.2)
        return holder

    def _block_offset(self) -> float:
        return self.sponge_thickness + HOLDER_HALF[2]

    def _sponge_particles(self, b: int):
        """World particles of env ``b``'s sponge (face frame: z from 0 at the front face to
        the thickness at the glued back), kinematic back layer, anchor = the face frame."""
        h = self.mpm_settings.particle_spacing
        lo = np.array([-SPONGE_HALF[0], -SPONGE_HALF[1], 0.0])
        hi = np.array([SPONGE_HALF[0], SPONGE_HALF[1], self.sponge_thickness])
        local = box_particles(lo, hi, h)
        F = self.face_frame[b].numpy()
        world = local @ F[:3, :3].T + F[:3, 3]
        self._sponge_rest[b] = local
        kin = local[:, 2] > self.sponge_thickness - self.mpm_settings.dx
        return world, kin, F

    def _init_task(self, env_idx, rng):
        self.target_compression[env_idx.cpu()] = torch.as_tensor(
            rng.uniform(*self.compression_range), dtype=torch.float32).reshape(len(env_idx))

    def compression(self) -> torch.Tensor:
        """[B] mean indentation of the front face near the pad apex / thickness."""
        self._ensure_cosims()
        apex = self.apex_in_face()
        h = self.mpm_settings.particle_spacing
        out = []
        for b, sim in enumerate(self.cosims):
            rest = self._sponge_rest[b]
            F = self.face_frame[b].numpy()
            x = sim.object_positions("sponge")
            local = (x - F[:3, 3]) @ F[:3, :3]
            front = rest[:, 2] < h
            near = front & (np.linalg.norm(rest[:, :2] - apex[b, :2].numpy(), axis=1) < self.probe_radius)
            if not near.any():
                out.append(0.0)
                continue
            out.append(float(np.mean(local[near, 2] - rest[near, 2])) / self.sponge_thickness)
        return torch.tensor(out, dtype=torch.float32)

    def _get_task_state(self):
        return {**super()._get_task_state(), "target_compression": self.target_compression.clone()}

    def _set_task_state(self, state, env_idx):
        super()._set_task_state(state, env_idx)
        self.target_compression[env_idx] = state["target_compression"].to(self.target_compression)

    def evaluate(self):
        c = self.compression()
        err = (c - self.target_compression).abs()
        px, py = self.pad_geometry(self.touch_pad).spec.layout.pitch
        force = self.tactile()[self.touch_pad]["pressure"].sum(dim=(1, 2)) * px * py  # stress-read normal force [N]
        return dict(success=(err < self.tolerance).to(self.device), compression=c.to(self.device),
                    compression_error=err.to(self.device), pad_force=force.to(self.device))

    def _get_obs_extra(self, info: dict):
        return dict(target_compression=self.target_compression[:, None].to(self.device))

    def compute_dense_reward(self, obs, action, info):
        dist = self.apex_in_face()[:, 2].clamp(max=0).abs().to(self.device, torch.float32)
        r_reach = 1 - torch.tanh(200.0 * dist)
        r_c = 1 - torch.tanh(10.0 * info["compression_error"])
        return r_reach + 2 * r_c + 2 * info["success"].float()

    def compute_normalized_dense_reward(self, obs, action, info):
        return self.compute_dense_reward(obs, action, info) / 5.0
