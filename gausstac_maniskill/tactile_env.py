"""The mechanism shared by the GaussTac tasks and a future ``make_tactile``, which turns a stock
ManiSkill task into the same task with GaussTac pads: what a ManiSkill env with co-simulated pads
does around ManiSkill's own step, independent of any one task.

* :class:`EnvSplatSource`: the env's co-simulators as the splat camera's scene;
  :func:`attach_splat_cameras`, :func:`invalidate_splat_backgrounds`: the env's splat cameras.
* :func:`pad_contacts`, :func:`fold_pad_reaction`: the pads' contacts of the last MPM step per
  pad link and object, and their reaction folded into the hand's drives and the two-way objects'
  springs (``pad_reaction=True``).
* :func:`copied`, :func:`batch_state`, :func:`task_state_leaves`, :func:`split_task_state`,
  :func:`stacked_flat_states`, :func:`load_flat_states`: copies of observations and infos, and
  the env state dict's ``"task"`` and ``"gausstac"`` parts.

The env is duck-typed (:class:`~gausstac_maniskill.tasks.base.GaussTacEnv`'s attributes):
nothing here imports the tasks. Units: SI; wrenches are force [N] and torque [N·m], world frame.
"""
from __future__ import annotations

import contextlib

import numpy as np
import sapien
import torch
from mani_skill.utils import common

from .sensors import GaussianSplatCamera, GaussianSplatCameraConfig, SplatSource

__all__ = ["EnvSplatSource", "attach_splat_cameras", "invalidate_splat_backgrounds", "pad_contacts",
           "fold_pad_reaction", "copied", "batch_state", "task_state_leaves", "split_task_state",
           "stacked_flat_states", "load_flat_states"]


class EnvSplatSource(SplatSource):
    """The env's co-simulators as the splat camera's scene (``env``: a
    :class:`~gausstac_maniskill.tasks.base.GaussTacEnv`)."""

    def __init__(self, env):
        self.env = env

    def render(self, viewmats, Ks, width, height, background, background_depth, lighting=None):
        """Every env's camera in one rasterizer call
        (:meth:`~gausstac_maniskill.batch.BatchedCosim.render`); an env without Gaussians
        shows the background as it is."""
        env = self.env
        env._ensure_cosims()
        out = env._batch.render(viewmats, Ks, width, height, background=background,
                                background_depth=background_depth, lighting=lighting)
        # depth: the Gaussians' where they cover the pixel, else the background's
        d_bg = background_depth.to(out.depth.device) if background_depth is not None else float("inf")
        depth = torch.where(out.alpha > 0.5, out.depth / out.alpha.clamp_min(1e-6), d_bg)
        return out.rgb, depth

    def _hidden_entities(self) -> list:
        """SAPIEN entities the Gaussians replace: the hand's links (when it has Gaussians), the
        MPM rigid objects that have Gaussians and the captured objects' actors (CPU sim; none on
        the GPU sim). A moving object drawn by its Gaussians then leaves SAPIEN's background
        picture unchanged, so it is taken once and reused."""
        env = self.env
        entities = []
        if not env.gpu_sim_enabled:
            if type(env.agent).gausstac_gaussians:
                entities += [obj.entity for link in env.agent.robot.links for obj in link._objs]
            entities += [ent for o in env._rigid.values() if o.gaussians is not None for ent in o.actor._objs]
            entities += [ent for o in env._captured.values() for ent in o.actor._objs]
        return entities

    def background_key(self):
        """Poses (and render visibility) of every SAPIEN entity that the background picture
        may show, i.e. all but the hidden ones; ``None`` on the GPU sim (not tracked)."""
        env = self.env
        if env.gpu_sim_enabled:
            return None
        hidden = {e.global_id for e in self._hidden_entities()}
        key = []
        for sub in env.scene.sub_scenes:
            for ent in sub.entities:
                if ent.global_id in hidden:
                    continue
                pose = ent.pose
                rb = ent.find_component_by_type(sapien.render.RenderBodyComponent)
                key += [ent.global_id, *pose.p, *pose.q, -1.0 if rb is None else rb.visibility]
        return np.asarray(key, dtype=np.float64)

    @contextlib.contextmanager
    def hidden(self):
        """Hide the hand's SAPIEN visuals (when it has Gaussians to replace them) and the
        captured objects' actors while the splat camera takes its background (CPU sim)."""
        entities = self._hidden_entities()
        bodies = []
        for ent in entities:
            rb = ent.find_component_by_type(sapien.render.RenderBodyComponent)
            if rb is not None and rb.visibility != 0:
                bodies.append(rb)
        for rb in bodies:
            rb.visibility = 0
        try:
            yield
        finally:
            for rb in bodies:
                rb.visibility = 1


def attach_splat_cameras(cams: dict, source: SplatSource) -> None:
    """In ``cams`` (uid -> ManiSkill camera, changed in place), make each camera configured by a
    :class:`~gausstac_maniskill.sensors.GaussianSplatCameraConfig` a
    :class:`~gausstac_maniskill.sensors.GaussianSplatCamera`, and attach every splat camera to
    ``source``."""
    for uid, cam in list(cams.items()):
        if isinstance(cam.config, GaussianSplatCameraConfig) and not isinstance(cam, GaussianSplatCamera):
            cams[uid] = GaussianSplatCamera.adopt(cam)
        if isinstance(cams[uid], GaussianSplatCamera):
            cams[uid].attach(source)


def invalidate_splat_backgrounds(cams: dict) -> None:
    """Make every splat camera of ``cams`` (uid -> camera) take SAPIEN's background afresh."""
    for cam in cams.values():
        if isinstance(cam, GaussianSplatCamera):
            cam.invalidate_background()


def pad_contacts(sim, pad_links: list[str], rigid_names: list[str]) -> np.ndarray:
    """[len(pad_links), len(rigid_names) + 1, 7] of one co-simulator: per pad link and object
    touched (rigid objects in ``rigid_names`` order, then soft objects) the force, torque about
    the link origin and indentation of :meth:`GaussTacSim.link_contacts
    <gausstac_maniskill.cosim.GaussTacSim.link_contacts>`."""
    order = {name: j for j, name in enumerate(rigid_names)}
    out = np.zeros((len(pad_links), len(rigid_names) + 1, 7))
    for i, link in enumerate(pad_links):
        for name, row in sim.link_contacts(link).items():
            out[i, order.get(name, len(rigid_names))] += row
    return out


def fold_pad_reaction(contacts: np.ndarray, friction: np.ndarray, joint_contacts: list, object_springs: list,
                      rigid_names: list[str], obj_w: dict[str, np.ndarray]) -> None:
    """Implicit pad reaction for the coming SAPIEN step: env b's pad contacts ``contacts[b]``
    ([pad links, rigid objects + 1, 7]) folded into its hand's drives (``joint_contacts[b]``,
    a :class:`~gausstac_maniskill.tasks.joint_contact.JointContact`), and each two-way object's
    share taken by its spring (``object_springs[b][j]``, an
    :class:`~gausstac_maniskill.tasks.contact_spring.ObjectSpring` or None) off that object's
    wrench ``obj_w[rigid_names[j]][b]`` [6] (in place). ``friction``: the Coulomb coefficient
    of each column of ``contacts``."""
    for b, (hand, springs) in enumerate(zip(joint_contacts, object_springs)):
        hand.fold(contacts[b], friction)
        for j, spring in enumerate(springs):
            if spring is not None:
                rows = list(zip(contacts[b][:, j], hand.links))
                obj_w[rigid_names[j]][b] -= spring.take(rows, friction[j])


def copied(tree):
    """``tree`` (nested dicts of tensors and arrays, as ManiSkill's obs and info) with every
    tensor cloned and every array copied; other leaves as they are."""
    if isinstance(tree, dict):
        return {k: copied(v) for k, v in tree.items()}
    if isinstance(tree, torch.Tensor):
        return tree.clone()
    if isinstance(tree, np.ndarray):
        return tree.copy()
    return tree


def batch_state(state: dict) -> dict:
    """Give a one-env state dict whose leaves lack the env axis (ManiSkill's CPU replay
    passes one step of a recorded ``env_states`` that way) its env axis; batched dicts
    are returned unchanged. The articulations' state tells which: ``[D]`` or ``[B, D]``."""
    probe = next(iter((state.get("articulations") or state.get("actors") or {}).values()), None)
    if probe is None or len(probe.shape) != 1:
        return state

    def add_axis(x):
        return {k: add_axis(v) for k, v in x.items()} if isinstance(x, dict) else x[None]

    return add_axis(state)




def task_state_leaves(task: dict, wrench: dict[str, np.ndarray], contacts: np.ndarray, num_envs: int) -> dict:
    """The ``"task"`` part of the env state dict, ``{}`` when empty: the task's variables
    ``task`` ([B, ...] tensors), the two-way wrench acting during the next SAPIEN step
    (``wrench_<object>`` [B, 6] float64) and the pads' contacts acting on their links
    (``pad_contacts`` [B, L * (O + 1) * 7] float64, when ``contacts`` is not empty); every
    leaf a copy, [B] leaves as [B, 1] (ManiSkill's replay indexes every state leaf as [..., D])."""
    if wrench:
        task = {**task, **{f"wrench_{n}": torch.as_tensor(w, dtype=torch.float64) for n, w in wrench.items()}}
    if contacts.size:
        task["pad_contacts"] = torch.as_tensor(contacts.reshape(num_envs, -1), dtype=torch.float64)
    return {k: (v[:, None] if v.ndim == 1 else v).clone() for k, v in task.items()}


def split_task_state(leaves: dict, rows: torch.Tensor, num_envs: int, task_now) -> tuple[dict, dict, object]:
    """:func:`task_state_leaves` taken apart for the envs ``rows`` (CPU tensors; a leaf with
    ``num_envs`` rows gives rows ``rows``, another is taken as the rows already): (task
    variables in the task's own shapes, the ``[B, 1]`` leaves back to ``[B]`` where
    ``task_now()`` (the task's current variables) has them ``[B]``; ``{object: wrench}``;
    the pad contacts or None)."""
    task = {}
    for k, v in leaves.items():
        # not common.to_tensor: it casts float64 to float32 (face frames, wrenches, pad contacts)
        v = v.detach().cpu() if isinstance(v, torch.Tensor) else torch.as_tensor(np.asarray(v))
        task[k] = v[rows] if v.shape[0] == num_envs else v  # rows of the envs being set
    wrench = {k[len("wrench_"):]: task.pop(k) for k in list(task) if k.startswith("wrench_")}
    contacts = task.pop("pad_contacts", None)
    if task:  # back to the task's own shapes ([B, 1] -> [B])
        now = task_now()
        task = {k: v[..., 0] if k in now and now[k].ndim == 1 and v.ndim == 2 else v for k, v in task.items()}
    return task, wrench, contacts


def stacked_flat_states(cosims: list) -> dict[str, torch.Tensor]:
    """The ``"gausstac"`` part of the env state dict: every co-simulator's
    :meth:`~gausstac_maniskill.cosim.GaussTacSim.flat_state`, stacked along a first env axis."""
    flats = [sim.flat_state() for sim in cosims]
    return {k: torch.from_numpy(np.stack([f[k] for f in flats])) for k in flats[0]}


def load_flat_states(cosims: list, flat: dict, rows: torch.Tensor, num_envs: int) -> None:
    """Restore env b's co-simulator, for each b of ``rows``, from :func:`stacked_flat_states`
    ``flat``: its row b where a leaf has ``num_envs`` rows, else its row in ``rows`` order."""
    for row, b in enumerate(rows.tolist()):
        state = {k: np.asarray(common.to_numpy(v))[b if np.shape(v)[0] == num_envs else row]
                 for k, v in flat.items()}
        cosims[b].load_flat_state(state)
