"""``GaussTac-SlideCube-v1``: keep the index pad in contact while sliding it across the cube.

Same scene as ``GaussTac-PressCube-v1``. Contact starts when the index pad's normal
force first exceeds ``contact_force``; from then on the force must never drop below it
(the episode fails if it does), and the apex must travel ``slide_distance`` (drawn in
[6, 10] mm) across the face. Success when it has, with contact kept throughout.
"""
from __future__ import annotations

import torch
from mani_skill.utils.registration import register_env

from ..task_checks import check_pair
from .press_cube import IndexCubeTask

__all__ = ["SlideCubeEnv"]


@register_env("GaussTac-SlideCube-v1", max_episode_steps=60)
class SlideCubeEnv(IndexCubeTask):
    """Slide the index fingertip across the cube's face without losing contact.

    Args:
        contact_force: force [N] above which the pad counts as touching (in [0.001, 10]).
        distance_range: slide distance range (lo, hi) [m], 1e-4 <= lo <= hi <= 0.02 (the
            face is 40 mm wide).
    """

    def __init__(self, *args, contact_force: float = 0.1, distance_range=(0.006, 0.010), **kwargs):
        self.check_range("contact_force", contact_force, 1e-3, 10.0, "N")
        self.contact_force = float(contact_force)
        self.distance_range = check_pair(self._env_id(), "distance_range", distance_range, 1e-4, 0.02, "m")
        super().__init__(*args, **kwargs)

    def _load_scene(self, options: dict):
        super()._load_scene(options)
        B = self.num_envs
        self.slide_distance = torch.full((B,), 0.008)
        self.contact_start = torch.zeros(B, 3, dtype=torch.float64)
        self.touched = torch.zeros(B, dtype=torch.bool)
        self.lost = torch.zeros(B, dtype=torch.bool)

    def _init_task(self, env_idx, rng):
        env_idx = env_idx.cpu()
        self.slide_distance[env_idx] = torch.as_tensor(rng.uniform(*self.distance_range),
                                                       dtype=torch.float32).reshape(len(env_idx))
        self.contact_start[env_idx] = 0.0
        self.touched[env_idx] = False
        self.lost[env_idx] = False

    def _after_control_step(self):
        super()._after_control_step()
        force = self.pad_force(self.touch_pad).cpu()
        apex = self.apex_in_face()
        on = force > self.contact_force
        start = on & ~self.touched
        self.contact_start[start] = apex[start]
        self.lost |= self.touched & ~on
        self.touched |= on

    def slid(self) -> torch.Tensor:
        """[B] distance [m] the apex has moved along the face since contact started."""
        d = (self.apex_in_face() - self.contact_start)[:, :2].norm(dim=1)
        return torch.where(self.touched, d, torch.zeros_like(d)).float()

    def _get_task_state(self):
        return {**super()._get_task_state(), "slide_distance": self.slide_distance.clone(),
                "contact_start": self.contact_start.clone(), "touched": self.touched.clone(),
                "lost": self.lost.clone()}

    def _set_task_state(self, state, env_idx):
        super()._set_task_state(state, env_idx)
        for k in ("slide_distance", "contact_start", "touched", "lost"):
            getattr(self, k)[env_idx] = state[k].to(getattr(self, k))

    def evaluate(self):
        slid = self.slid()
        force = self.pad_force(self.touch_pad)
        ok = self.touched & ~self.lost
        return dict(success=(ok & (slid >= self.slide_distance)).to(self.device), fail=self.lost.to(self.device),
                    slid=slid.to(self.device), force=force, in_contact=(force > self.contact_force))

    def _get_obs_extra(self, info: dict):
        return dict(slide_distance=self.slide_distance[:, None].to(self.device),
                    slid=self.slid()[:, None].to(self.device))

    def compute_dense_reward(self, obs, action, info):
        contact = info["in_contact"].float()
        progress = (info["slid"] / self.slide_distance.to(self.device)).clamp(max=1.0)
        dist = self.apex_in_face()[:, 2].clamp(max=0).abs().to(self.device, torch.float32)
        r = (1 - torch.tanh(200.0 * dist)) + contact + 2 * progress * contact
        r = r + 2 * info["success"].float() - 2 * info["fail"].float()
        return r

    def compute_normalized_dense_reward(self, obs, action, info):
        return self.compute_dense_reward(obs, action, info) / 6.0
