"""GaussTacEnv: a ManiSkill task whose hand has soft tactile pads and whose camera splats Gaussians.

``env.step``: SAPIEN physics (``sim_freq`` substeps) -> link poses [B, L, 4, 4] and object poses
-> ``BatchedCosim.step`` (every env's pads and soft objects in one batch, dt = control timestep)
-> evaluate / reward -> obs: agent/extra, splat ``sensor_data``, ``obs["tactile"]``. Tasks subclass
it like any ManiSkill task and register what the pads touch with :meth:`GaussTacEnv.add_mpm_rigid`
and :meth:`GaussTacEnv.add_mpm_soft` in ``_load_scene``; the co-simulators are rebuilt each episode
from the poses ``_initialize_episode`` leaves, and their state is in ``get_state_dict`` (exact replay).

In SAPIEN a pad link collides only with its rigid core (:func:`~gausstac_maniskill.agents.core_urdf`):
the pad solver owns the contact in the soft layer, the core is a hard stop. Two-way objects take the
pads' reaction; with ``pad_reaction`` the links take it too, through the hand's joint drives
(:mod:`.joint_contact`) and one implicit spring per two-way object (:mod:`.contact_spring`), or with
``"explicit"`` as forces one SAPIEN step late (stable from :data:`PAD_REACTION_MIN_FREQ` Hz). The hooks
call :mod:`~gausstac_maniskill.tactile_env`, :mod:`~gausstac_maniskill.task_checks`,
:mod:`~gausstac_maniskill.scene_objects` and :mod:`~gausstac_maniskill.physx`. Units: SI.
"""
from __future__ import annotations

import copy
import dataclasses
import os
import time
from functools import partial
from typing import Callable

import numpy as np
import sapien
import torch
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import common

from .. import backend
from ..agents.base import GaussTacAgent, load_hand_closed_links, load_hand_gaussians, load_hand_lod
from ..batch import BatchedCosim
from ..config import Material, PadSolverSettings, SolverSettings
from ..cosim import GaussTacSim
from ..errors import ConfigError
from ..geometry.colliders import Collider
from ..physx import apply_wrench, batched_pose
from ..pose.sapien_source import SapienPoseSource
from ..transforms import vec7_to_matrix
from ..render import RigidLayer
from ..scene_objects import CapturedObject, RigidObject, SoftObject, captured_object, load_scene_capture
from ..sensors import GaussianSplatCameraConfig, TactileSensor, TactileSensorConfig
from ..tactile_env import (EnvSplatSource, attach_splat_cameras, batch_state, copied, fold_pad_reaction,
                           invalidate_splat_backgrounds, load_flat_states, pad_contacts, split_task_state,
                           stacked_flat_states, task_state_leaves)
from ..task_checks import (check_action, check_choice, check_flag, check_optical, check_pad_coupling, check_pair,
                           check_range, check_render_mode, check_sim_backend, check_size, check_splat_look)
from .contact_spring import ObjectSpring
from .joint_contact import JointContact

__all__ = ["GaussTacEnv", "RigidObject", "SoftObject", "CapturedObject", "batched_pose", "SCENE_BACKGROUND",
           "PAD_REACTION_MIN_FREQ", "check_range", "check_pair", "check_flag", "check_choice", "check_size"]

#: SAPIEN rate [Hz] from which ``pad_reaction="explicit"`` held a hand closed hard on a fixed
#: cube (``bench close --reaction explicit``: flung fingers at 100, 500 and 1000 Hz, none at 2000 Hz)
PAD_REACTION_MIN_FREQ = 2000

#: splat camera background [RGB in 0..1] behind a captured scene (``splat_background=None``)
SCENE_BACKGROUND = (0.0, 0.0, 0.0)


class GaussTacEnv(BaseEnv):
    """Base class of GaussTac tasks.

    Args (in addition to ManiSkill's ``BaseEnv`` arguments):
        robot_uids: a GaussTac agent (default ``allegro_hand_right_gausstac``).
        mpm_dx: MPM grid spacing [m] (pads: 2 particles per cell). The default 1 mm
            resolves the 4 mm pads (4 cells); 2 mm is 8× cheaper but under-resolved (a
            ``ResolutionWarning`` says so; forces are not converged, see BENCHMARKS.md).
        mpm_sleep_margin: a pad farther than this from every object sleeps [m], in [0, 1].
        splat_size: (width, height) of the default splat camera ``splat_camera`` [pixels].
        splat_lod: a splat camera draws the coarsest of the hand asset's levels of detail
            (``links.json`` ``levels``: 2.5 and 3 mm for the Allegro hand, against 2 mm) whose
            splats (in-plane σ = 0.9 spacing) are no wider than its pixels at the hand: the
            2.5 mm hand in PressCube, SlideCube and SqueezeSponge (2.3 mm pixels), the 3 mm
            hand in the other tasks' 128 × 128 cameras (3.5–3.8 mm). Nearly the same look and
            depth against SAPIEN, 1.1–1.3× less time (BENCHMARKS.md). ``False``:
            always the fine hand.
        splat_cull: the splat camera skips the hand's Gaussians that face away from it, on the
            links the asset marks closed (``links.json`` ``closed_links``): a nearer front side
            hides them (BENCHMARKS.md). ``False``: draw every Gaussian.
        render_size: (width, height) of the human render camera (``render_mode="rgb_array"``)
            [pixels]. ``render_mode="human"`` (SAPIEN's viewer window) needs a display: on Linux
            without ``DISPLAY`` or ``WAYLAND_DISPLAY`` it is a ``ConfigError`` naming ``rgb_array``.
        splat_background: ``"sapien"`` (composite over SAPIEN's render), an RGB triple in
            [0, 1], or ``None`` (default): ``"sapien"`` without a ``scene_ply``,
            :data:`SCENE_BACKGROUND` (black) with one.
        scene_ply: a captured 3DGS scene (INRIA ``.ply``, SH degree 0..3, e.g. exported by
            gsplat, nerfstudio or the INRIA code) drawn around the task by the splat camera,
            or ``"example"`` for the packaged table-top capture
            (:mod:`gausstac_maniskill.splat.example_scene`). Its Gaussians are splatted in the
            same pass as the hand's and depth-sorted with them. **With a scene, SAPIEN's
            background picture is skipped** (``splat_background=None`` gives a plain colour):
            the capture replaces the surroundings (ground plane, SAPIEN lighting), the
            hand, pads and task objects have Gaussians of their own, and the frame costs no
            SAPIEN render. SAPIEN actors without Gaussians are then invisible to the splat
            camera; ``splat_background="sapien"`` composites over SAPIEN's render again
            (the ground plane then shows where it is nearer than the capture). Needs
            ``camera="splat"``.
        scene_pose: the capture frame -> world similarity: a
            :class:`~gausstac_maniskill.splat.capture.Similarity`, a dict ``{"scale": s,
            "rotation": (w, x, y, z), "translation": (x, y, z) m}`` (JSON-friendly, what
            ManiSkill's recorder stores) or a 4x4 ``[[s R, t], [0, 1]]``. ``None``: identity,
            or ``EXAMPLE_PLACEMENT`` for ``scene_ply="example"``. A placed scene wider than
            100 m or narrower than 1 mm gets an ``AssetWarning`` suggesting a scale.
        splat_lighting: ``"scene"`` (default: the hand's, pads' and objects' Gaussians are
            shaded with the SAPIEN scene's ambient and directional lights, as SAPIEN shades
            their meshes), ``"baked"`` (their colours drawn as stored, unlit) or a
            :class:`~gausstac_maniskill.splat.lighting.Lighting`; see
            :class:`~gausstac_maniskill.sensors.GaussianSplatCameraConfig`. A captured
            scene's Gaussians are never shaded (their lighting is in their colours).
        camera: ``"splat"`` (default cameras are :class:`GaussianSplatCamera`) or ``"sapien"``
            (plain SAPIEN cameras at the same poses: rigid meshes only, no pad deformation).
        record_mpm_state: put the MPM state in ``get_state_dict`` (exact replay; ~150 B per
            particle per recorded step).
        pad_reaction: apply the pads' contact reaction to their links in SAPIEN: what the
            pads push on objects, the fingers feel, equal and opposite (the MPM then steps
            after every SAPIEN step). ``True`` (= ``"implicit"``): folded into the hand's
            joint drives for each SAPIEN step
            (:mod:`~gausstac_maniskill.tasks.joint_contact`; at rest the drives' torques
            balance the pad's wrench through the finger's Jacobian), and on two-way objects
            through one implicit spring per object (:mod:`~gausstac_maniskill.tasks.contact_spring`);
            stable at ManiSkill's 100 Hz. It runs SAPIEN with PhysX's PGS solver
            (``enable_tgs=False``; TGS raises a ``ConfigError``) and needs ``"force"``-mode
            drives. ``"explicit"``: as forces one SAPIEN step late, stable only
            at a high ``sim_freq`` because the hand's distal links are light (10-40 g): a
            hand closed hard on a fixed cube flings its fingers at 100-1000 Hz and holds at
            2000 Hz (``bench close --reaction explicit``, BENCHMARKS.md); a warning says so
            below :data:`PAD_REACTION_MIN_FREQ`. ``False`` (default): the hand is driven
            kinematically as far as the pads are concerned (the rigid cores still stop a
            finger), and the pads crush against their cores when a finger presses hard.
        pad_solver: ``"auto"`` (default): ``"fem"``, except ``"mpm"`` in a task with a soft object
            (the sponge tasks) when ``fem_model="neo_hookean"``; :attr:`pad_solver_used` says which.
            ``"fem"``: each env's pads solved at equilibrium after every MPM step
            (:class:`~gausstac_maniskill.fem.sensor.EquilibriumPad`; no pseudo-mass, no time
            step; a soft object meets each pad's surface, shaped as the pad was last solved,
            and loads it: :meth:`~gausstac_maniskill.cosim.GaussTacSim.add_soft_object`);
            its normal forces within 4.3 % of its finest grid on the product pad at the default
            ``mpm_dx`` (the sphere's sliding friction force +5.7 %),
            about 10× faster than the MPM pads (BENCHMARKS.md). Its linear model
            warns where a pad is pressed beyond half its layer. At the default ``mpm_dx`` a pad
            shape's first contact on a machine computes its compliance and its maps' response
            (about 55 s on 2 cores, with progress bars; then kept under
            ``~/.cache/gausstac_maniskill``). ``"mpm"``: the pads are explicit MPM particles
            (finite strain; soft objects too).
        fem_model: the ``"fem"`` pads' material, ``"linear"`` (default) or ``"neo_hookean"``.
        fem_precompute: the ``"fem"`` pads' compliance among all their surface points computed
            once (True) or solved point by point as contact reaches them (False); default
            (None): in full up to 256 MiB (the Allegro fingertips at the default ``mpm_dx``),
            point by point above, with a :class:`~gausstac_maniskill.errors.CostWarning`
            (:class:`~gausstac_maniskill.cosim.GaussTacSim`'s ``fem_precompute``).
        optical: optical sensors on the pads: an optical preset (``"gelsight"``,
            ``"gelsight_mini"`` or a calibration folder: :func:`~gausstac_maniskill.optical.preset`)
            for every pad, or ``{pad: preset}`` for some. Each such pad's ``obs["tactile"][pad]``
            then also holds ``"rgb"`` [B, H, W, 3] uint8, the sensor's image of the pad's surface
            over its taxel layout, and ``"markers"`` [B, N, 2] px (dict obs modes; the flat
            ``"state"`` mode leaves them out). Default None: no image, no cost.
        optical_width: the optical images' width [px] across the pad's x (along the finger);
            the height follows the layout's aspect (square pixels).
    """

    SUPPORTED_ROBOTS = ["allegro_hand_right_gausstac"]
    agent: GaussTacAgent

    def __init__(self, *args, robot_uids="allegro_hand_right_gausstac", mpm_dx: float = 1.0e-3,
                 mpm_sleep_margin: float = 5.0e-3, splat_size=(128, 128), render_size=(256, 256),
                 splat_background=None, record_mpm_state: bool = True, camera: str = "splat",
                 scene_ply: str | os.PathLike | None = None, scene_pose=None, splat_lighting="scene",
                 pad_reaction: bool = False, splat_lod: bool = True, splat_cull: bool = True,
                 pad_solver: str = "auto", fem_model: str = "linear", fem_precompute: bool | None = None,
                 optical=None, optical_width: int = 320, **kwargs):
        backend.ensure_init()
        check_sim_backend(kwargs.get("num_envs", 1), kwargs.get("sim_backend", "auto"))
        task = self._env_id()
        check_render_mode(task, kwargs.get("render_mode"))
        if not (isinstance(mpm_dx, (int, float)) and 2e-4 <= mpm_dx <= 1e-2):
            raise ConfigError(f"mpm_dx={mpm_dx!r} m must be a number in [2e-4, 1e-2]")
        check_range(task, "mpm_sleep_margin", mpm_sleep_margin, 0.0, 1.0, "m")
        check_size(task, "splat_size", splat_size)
        check_size(task, "render_size", render_size)
        for name, flag in (("record_mpm_state", record_mpm_state), ("splat_lod", splat_lod),
                           ("splat_cull", splat_cull)):
            check_flag(task, name, flag)
        check_splat_look(task, splat_background, splat_lighting)
        self.mpm_settings = SolverSettings(dx=float(mpm_dx))
        #: the pads' solver settings, from the kwargs pad_solver, fem_model, fem_precompute, mpm_sleep_margin
        self.pad_settings = PadSolverSettings(solver=pad_solver, fem_model=fem_model, fem_precompute=fem_precompute,
                                              sleep_margin=mpm_sleep_margin)
        #: ``{pad or None (every pad): optical preset}`` from the kwarg ``optical`` (checked here)
        self.optical = check_optical(task, optical, optical_width)
        self.optical_width = int(optical_width)
        self.splat_size = tuple(int(v) for v in splat_size)
        self.render_size = tuple(int(v) for v in render_size)
        self.record_mpm_state = bool(record_mpm_state)
        self.splat_lod = bool(splat_lod)
        self.splat_cull = bool(splat_cull)
        if pad_reaction not in (False, True, "implicit", "explicit"):
            raise ConfigError(f"pad_reaction={pad_reaction!r}: use False, True (= 'implicit') or 'explicit'")
        #: how the pads' reaction reaches their links: None, "implicit" or "explicit"
        self.pad_coupling = None if not pad_reaction else "implicit" if pad_reaction is True else pad_reaction
        if camera not in ("splat", "sapien"):
            raise ConfigError(f"camera={camera!r}: use 'splat' (Gaussian Splatting) or 'sapien'")
        self.camera_kind = camera
        #: the placed captured scene (world frame) or None; see ``scene_ply``
        self.scene_gaussians = load_scene_capture(scene_ply, scene_pose, camera)
        self._scene_layer = None if self.scene_gaussians is None else RigidLayer(self.scene_gaussians)
        if splat_background is None:
            splat_background = "sapien" if self.scene_gaussians is None else SCENE_BACKGROUND
        self.splat_background = splat_background
        self.splat_lighting = splat_lighting
        self._captured: dict[str, CapturedObject] = {}
        self.cosims: list[GaussTacSim] = []
        self._rigid: dict[str, RigidObject] = {}
        self._soft: dict[str, SoftObject] = {}
        self._wrench: dict[str, np.ndarray] = {}  # object -> [B, 6] acting during the next SAPIEN step
        # [B, pad links, rigid objects + soft, 7] pad contacts of the last MPM step (pad_reaction)
        self._contacts = np.zeros((0, 0, 1, 7))
        self._joint_contacts: list = []  # [B] the pads' reaction folded into the hand's drives (pad_reaction)
        self._object_springs: list = []  # [B][rigid object]: springs on two-way objects, else None (pad_reaction)
        self._cosim_stale = True
        #: wall time [s] of the parts of the last step: physics, mpm, tactile, render
        self.step_timing: dict[str, float] = {}
        self._splat_source = EnvSplatSource(self)
        if robot_uids is not None:  # None: the task below sets its own (a stock task, make_tactile)
            kwargs["robot_uids"] = robot_uids
        super().__init__(*args, **kwargs)
        check_pad_coupling(self.pad_coupling, self.gpu_sim_enabled, self.sim_config.scene_config.enable_tgs,
                           self.sim_freq, PAD_REACTION_MIN_FREQ)

    @classmethod
    def check_range(cls, name: str, value, low: float, high: float, unit: str = "") -> None:
        """``ConfigError`` naming the task and argument ``name`` unless ``value`` is a number
        in [low, high] (:func:`~gausstac_maniskill.task_checks.check_range`)."""
        check_range(cls._env_id(), name, value, low, high, unit)

    @classmethod
    def _env_id(cls) -> str:
        """The id the task is registered under (``"GaussTac-PressCube-v1"``), or the class name."""
        from mani_skill.utils.registration import REGISTERED_ENVS

        return next((k for k, v in REGISTERED_ENVS.items() if v.cls is cls), cls.__name__)

    @property
    def pad_reaction(self) -> bool:
        """Whether the pads' reaction acts on their links (see ``pad_coupling``)."""
        return self.pad_coupling is not None

    @property
    def mpm_world(self):
        """The one :class:`~gausstac_maniskill.mpm.MPMWorld` that holds every env's pads and
        objects (rebuilt after a reset or reconfiguration)."""
        self._ensure_cosims()
        return self._batch.world

    @property
    def _default_sim_config(self):
        cfg = super()._default_sim_config
        if self.pad_coupling == "implicit":  # the object springs need PGS (tasks/contact_spring.py)
            cfg.scene_config.enable_tgs = False
        return cfg

    # ------------------------------------------------------------------ set-up
    def _load_agent(self, options: dict, initial_agent_poses=None, *args, **kwargs):
        super()._load_agent(options, sapien.Pose() if initial_agent_poses is None else initial_agent_poses,
                            *args, **kwargs)
        if not isinstance(self.agent, GaussTacAgent) or not self.agent.gausstac_pads:
            uid = getattr(self.agent, "uid", self.robot_uids)
            raise ConfigError(f"robot_uids={uid!r} has no GaussTac pads: use 'allegro_hand_right_gausstac' or an "
                              "agent made with gausstac_maniskill.agents.add_gausstac_pads(...)")
        self._pad_links = list(dict.fromkeys(p.link for p in self.agent.gausstac_pads))  # read every SAPIEN step

    #: height [m] of the ground plane under the hand (``None``: no ground)
    ground_altitude: float | None = -0.15

    def _load_scene(self, options: dict):
        """Builds the ground; tasks call it first, then build their actors and register
        what the MPM sees (:meth:`add_mpm_rigid`, :meth:`add_mpm_soft`)."""
        if self.ground_altitude is not None:
            from mani_skill.utils.building.ground import build_ground

            self.ground = build_ground(self.scene, floor_width=4, altitude=self.ground_altitude,
                                       texture_square_len=0.1)

    def add_mpm_rigid(self, name: str, actor, collider: Collider, gaussians=None, two_way: bool = False,
                      offset=None) -> None:
        """Let the pads feel ``actor`` through ``collider``, posed at ``offset`` ([4, 4], the
        collider's pose in the actor frame; default identity) by the actor's pose. ``two_way``:
        apply the pads' reaction wrench to the (dynamic) actor in SAPIEN. ``gaussians``: the
        actor's look for the splat camera (actor frame); without them SAPIEN draws it."""
        if name in self._rigid or name in self._soft or name in self._captured:
            raise ConfigError(f"MPM object {name!r} already registered")
        if two_way and getattr(actor, "px_body_type", "dynamic") != "dynamic":
            raise ConfigError(f"two_way coupling needs a dynamic actor; {name!r} is {actor.px_body_type}")
        self._rigid[name] = RigidObject(name, actor, collider, gaussians, bool(two_way),
                                        None if offset is None else np.asarray(offset, np.float64))

    def add_captured_object(self, name: str, actor, capture, placement=None) -> None:
        """Draw ``actor`` in the splat camera with captured Gaussians that follow its pose
        every step (call it in ``_load_scene``).

        Args:
            name: unique among the env's objects.
            actor: a ManiSkill ``Actor`` with a collision shape (``add_*_collision`` in its
                builder): SAPIEN simulates it, the Gaussians only draw it. Its SAPIEN
                visuals are hidden while the splat camera takes SAPIEN's background.
            capture: an INRIA ``.ply`` path (read by
                :func:`~gausstac_maniskill.splat.capture.load_capture`, with its checks) or
                a ``GaussianSet``, in the capture's frame.
            placement: capture frame -> actor frame (``Similarity``, dict or 4x4, as
                ``scene_pose``); ``None``: identity.

        Raises:
            ConfigError: a name already used, or an actor without a collision shape.

        Warns:
            AssetWarning: the placed Gaussians are more than twice as large or small as the
                actor's collision mesh (the message gives the scale that would match).

        For the pads to feel the object too, register it with :meth:`add_mpm_rigid`
        instead, with ``gaussians=load_capture(ply, placement)``.
        """
        if name in self._rigid or name in self._soft or name in self._captured:
            raise ConfigError(f"object {name!r} already registered")
        self._captured[name] = captured_object(name, actor, capture, placement)

    def add_mpm_soft(self, name: str, particles: Callable[[int], tuple], material: Material) -> None:
        """A deformable MPM object (not in SAPIEN; the splat camera draws it): see
        :class:`~gausstac_maniskill.scene_objects.SoftObject`. ``particles`` is called when
        each episode's co-simulator is built."""
        if name in self._rigid or name in self._soft or name in self._captured:
            raise ConfigError(f"MPM object {name!r} already registered")
        self._soft[name] = SoftObject(name, particles, material)

    def _reconfigure(self, options=dict()):
        # a reconfiguration rebuilds the scene: tasks register their MPM objects again
        self._rigid.clear()
        self._soft.clear()
        self._captured.clear()
        self._wrench = {}
        self.cosims = []
        self._cosim_stale = True
        super()._reconfigure(options)

    def _after_reconfigure(self, options):
        super()._after_reconfigure(options)
        self._joint_contacts, self._object_springs = [], []
        if self.pad_coupling == "implicit":
            for b, sub in enumerate(self.scene.sub_scenes):
                links = [self.agent.robot.links_map[name]._objs[b] for name in self._pad_links]
                self._joint_contacts.append(JointContact(self.agent.robot._objs[b], links))
                self._object_springs.append([ObjectSpring(sub, o.actor._objs[b]) if o.two_way else None
                                             for o in self._rigid.values()])
        self._pose_source = SapienPoseSource(self.agent)
        self._cosim_stale = True
        self.tactile_sensor = TactileSensor(TactileSensorConfig(uid="tactile", optical=self._optical_pads()),
                                            self.tactile,
                                            self.pad_names, device=self.device)

    def _optical_pads(self) -> dict | None:
        """``{pad: optical preset sized to its layout}`` for the pads with an optical sensor (the
        task's ``optical``, else the agent's ``gausstac_optical``)."""
        chosen = self.optical or self.agent.gausstac_optical  # the task's, else the agent's
        if not chosen:
            return None
        from ..optical import pad_preset

        specs = {p.name: p for p in self.agent.gausstac_pads}
        named = {pad: chosen[pad] for pad in chosen if pad is not None}
        unknown = sorted(set(named) - set(specs))
        if unknown:
            raise ConfigError(f"{self._env_id()}: optical names pads {unknown} that the hand does not have; "
                              f"its pads: {sorted(specs)}")
        every = {pad: chosen[None] for pad in specs} if None in chosen else {}
        return {pad: pad_preset(sensor, specs[pad].layout, self.optical_width)
                for pad, sensor in {**every, **named}.items()}

    @property
    def action_joint_index(self) -> list[int]:
        """Index into the articulation's qpos of each joint the controller drives, in
        action order (Allegro: actions are joint_0.0..15.0, qpos is 0, 4, 8, 12, 1, ...)."""
        names = [j.name for j in self.agent.robot.get_active_joints()]
        return [names.index(n) for n in self.agent.controller.config.joint_names]

    def qpos_in_action_order(self) -> torch.Tensor:
        """[B, J] current joint angles [rad] in action order."""
        return self.agent.robot.get_qpos()[:, self.action_joint_index]

    def action_order_to_qpos(self, q: torch.Tensor) -> torch.Tensor:
        """Joint angles ``[..., J]`` in action order -> articulation qpos order."""
        out = torch.empty_like(q)
        out[..., self.action_joint_index] = q
        return out

    @property
    def pad_names(self) -> list[str]:
        """Pad ids, the keys of ``obs["tactile"]``."""
        return [p.name for p in self.agent.gausstac_pads]

    def pad_geometry(self, pad: str):
        """The :class:`~gausstac_maniskill.tactile.Pad` (link-frame particles and sensor frame)
        of pad ``pad`` at this env's resolution (cached)."""
        from ..tactile import pad_geometry

        spec = next((p for p in self.agent.gausstac_pads if p.name == pad), None)
        if spec is None:
            raise ConfigError(f"unknown pad {pad!r}; pads: {self.pad_names}")
        return pad_geometry(spec, type(self.agent).pad_urdf(), self.mpm_settings.particle_spacing,
                            self.mpm_settings.dx)

    def pad_frame(self, pad: str) -> torch.Tensor:
        """[B, 4, 4] world pose of ``pad``'s sensor frame now (z out of the pad, origin at
        its apex, x along the finger), from SAPIEN's link poses."""
        geo = self.pad_geometry(pad)
        names = self._pose_source.link_names
        P = self._pose_source.all_link_poses()[:, names.index(geo.spec.link)].detach().cpu().double()
        return (P @ torch.tensor(geo.sensor_frame)).to(torch.float64)  # a copy: the cached pad is read-only

    def _splat_camera_pose(self) -> sapien.Pose:
        """Pose of the default splat and render cameras (tasks override)."""
        from mani_skill.utils import sapien_utils

        return sapien_utils.look_at(eye=[0.3, -0.12, 0.3], target=[0.0, 0.03, 0.05])

    def _camera_config(self, uid: str, size) -> CameraConfig:
        w, h = size
        common_args = dict(uid=uid, pose=self._splat_camera_pose(), width=w, height=h, fov=np.pi / 3, near=0.01,
                           far=10.0)
        if self.camera_kind == "sapien":
            return CameraConfig(**common_args)
        return GaussianSplatCameraConfig(**common_args, background=self.splat_background,
                                         lighting=self.splat_lighting)

    @property
    def _default_sensor_configs(self):
        return [self._camera_config("splat_camera", self.splat_size)]

    @property
    def _default_human_render_camera_configs(self):
        return self._camera_config("render_camera", self.render_size)

    def _setup_sensors(self, options: dict):
        super()._setup_sensors(options)
        for cams in (self._sensors, self._human_render_cameras):
            attach_splat_cameras(cams, self._splat_source)
        self.scene.sensors = self._sensors
        self.scene.human_render_cameras = self._human_render_cameras

    # ------------------------------------------------------------------ co-simulation
    def _object_poses(self) -> dict[str, np.ndarray]:
        """``{name: [B, 4, 4]}`` world poses [m] of the MPM rigid objects' actors."""
        poses = {}
        for name, obj in self._rigid.items():
            T = vec7_to_matrix(obj.actor.pose.raw_pose).detach().cpu().double().numpy()
            poses[name] = T if obj.offset is None else T @ obj.offset
        return poses

    def _link_poses(self) -> torch.Tensor:
        """[B, L, 4, 4] world poses of every link of the pose source (``link_names`` order)."""
        return self._pose_source.all_link_poses().detach()

    def _build_cosims(self) -> None:
        """(Re)build the co-simulator at rest, from the current SAPIEN poses: one MPM world
        holding every env (:class:`~gausstac_maniskill.batch.BatchedCosim`); ``self.cosims[b]``
        is env b's scene in it."""
        t0 = time.perf_counter()
        agent = type(self.agent)
        hand = None
        hand_lod, closed = None, ()
        if agent.gausstac_gaussians:
            hand = load_hand_gaussians(agent.gausstac_gaussians)
            hand_lod = load_hand_lod(agent.gausstac_gaussians) if self.splat_lod else None
            closed = load_hand_closed_links(agent.gausstac_gaussians) if self.splat_cull else ()
        objects = self._object_poses()
        settings = self.mpm_settings
        if self.mpm_every_sim_step:
            # the pads' reaction moves SAPIEN bodies: their pseudo-mass stays what the coupling
            # was built and measured with (a held pad's larger one jolted a pinched cube)
            settings = dataclasses.replace(settings, hold_scaling=1.0)
        self._batch = BatchedCosim(agent.gausstac_pads, self._pose_source.link_names, self._link_poses(),
                                   urdf=agent.pad_urdf(), settings=settings, pad_settings=self.pad_settings)
        self.cosims = self._batch.scenes
        for name, obj in self._rigid.items():
            cols = [copy.deepcopy(obj.collider) for _ in range(self.num_envs)]
            for b, col in enumerate(cols):
                col.pose = objects[name][b]
            self._batch.add_rigid_object(name, cols)
        for b, sim in enumerate(self.cosims):
            for name, soft in self._soft.items():
                x, kin, anchor = soft.particles(b)
                link = None
                if kin is not None and np.any(kin):
                    link = f"{name}_anchor"
                    sim.add_link(link, np.eye(4) if anchor is None else np.asarray(anchor, np.float64))
                sim.add_soft_object(name, x, soft.material, link=link, kinematic=kin)
            if hand is not None or any(o.gaussians is not None for o in self._rigid.values()) or self._soft \
                    or self._scene_layer is not None or self._captured:
                sim.attach_gaussians(hand[0] if hand else None, hand[1] if hand else (),
                                     {n: o.gaussians for n, o in self._rigid.items() if o.gaussians is not None},
                                     hand_lod=hand_lod, closed_links=closed)
                self._add_captured_layers(sim, b)
        #: the pads' solver in this scene, ``"fem"`` or ``"mpm"``: ``pad_solver`` with "auto" resolved
        #: by :meth:`GaussTacSim.add_soft_object <gausstac_maniskill.cosim.GaussTacSim.add_soft_object>`
        self.pad_solver_used = self.cosims[0].pad_solver
        self._wrench = {n: np.zeros((self.num_envs, 6)) for n, o in self._rigid.items() if o.two_way}
        self._contacts = np.zeros((self.num_envs, len(self._pad_links) if self.pad_reaction else 0,
                                   len(self._rigid) + 1, 7))
        # Coulomb coefficient per column of _contacts: the rigid objects', then the soft objects'
        self._contact_friction = np.array([o.collider.friction for o in self._rigid.values()]
                                          + [self.mpm_settings.soft_friction])
        self._cosim_stale = False
        self._tactile_maps = None
        self.step_timing["cosim_build"] = time.perf_counter() - t0

    def _add_captured_layers(self, sim: GaussTacSim, b: int) -> None:
        """Give env ``b``'s splat scene the captured background and captured objects."""
        if self._scene_layer is not None:
            sim.add_render_layer(self._scene_layer)  # static: one posed copy shared by every env
        if self._captured:
            from ..splat import GaussianSet

            objs = list(self._captured.values())
            g = GaussianSet.cat([o.gaussians.replace(link_id=torch.full_like(o.gaussians.link_id, i))
                                 for i, o in enumerate(objs)])
            sim.add_render_layer(RigidLayer(g, poses=partial(self._captured_poses, b)))

    def _captured_poses(self, b: int) -> np.ndarray:
        """[A, 4, 4] world poses of env ``b``'s captured-object actors (registration order)."""
        return np.stack([vec7_to_matrix(o.actor.pose.raw_pose)[b].detach().cpu().double().numpy()
                         for o in self._captured.values()])

    def _ensure_cosims(self) -> None:
        if self._cosim_stale or not self.cosims:
            self._build_cosims()

    def reset(self, seed=None, options=None):
        self._cosim_stale = True
        for cams in (getattr(self, "_sensors", {}), getattr(self, "_human_render_cameras", {})):
            # a new episode may look different in ways no pose shows (randomised materials)
            invalidate_splat_backgrounds(cams)
        t0 = time.perf_counter()
        out = super().reset(seed=seed, options=options)
        self.step_timing["reset"] = time.perf_counter() - t0
        return out

    def get_info(self) -> dict:
        """ManiSkill's info (``evaluate()`` and ``elapsed_steps``), every tensor a copy: a
        kept info never changes with later steps."""
        self._ensure_cosims()  # after _initialize_episode placed the hand and objects
        return copied(super().get_info())

    @property
    def mpm_every_sim_step(self) -> bool:
        """Whether the MPM steps after every SAPIEN step (``sim_timestep``) instead of once
        per control step: on with ``pad_reaction`` or a two-way coupled object, so that
        the reaction is renewed every SAPIEN step, not every control step (explicit coupling
        of a mass m to a pad of contact stiffness k is stable for m > k·dt²/4; the contact
        springs of ``pad_reaction=True`` predict only one SAPIEN step). The total number of
        MPM substeps is about the same."""
        return self.pad_reaction or any(o.two_way for o in self._rigid.values())

    def _step_mpm(self, dt: float) -> None:
        self._ensure_cosims()
        t0 = time.perf_counter()
        objects = self._object_poses()
        self._batch.advance(self._link_poses(), dt, objects)
        self._tactile_maps = None
        for b, sim in enumerate(self.cosims):
            for name in self._wrench:
                f, tau = sim.object_wrench(name)  # torque about the collider's origin
                offset = self._rigid[name].offset
                if offset is not None:  # ... moved to the actor's (apply_wrench): the arm from actor to collider
                    R = objects[name][b][:3, :3] @ offset[:3, :3].T  # the actor's rotation
                    tau = tau + np.cross(R @ offset[:3, 3], f)
                self._wrench[name][b] = np.concatenate([f, tau])
            if self._contacts.shape[1]:
                self._contacts[b] = pad_contacts(sim, self._pad_links, list(self._rigid))
        self.step_timing["mpm"] = self.step_timing.get("mpm", 0.0) + time.perf_counter() - t0

    def _after_simulation_step(self):
        super()._after_simulation_step()
        if self.mpm_every_sim_step:
            self._step_mpm(self.sim_timestep)

    def _after_control_step(self):
        super()._after_control_step()
        self._canonical_sapien_state()
        if not self.mpm_every_sim_step:
            self._step_mpm(self.control_timestep)
        t1 = time.perf_counter()
        self.tactile()  # read the maps now (kept for evaluate / obs)
        self.step_timing["tactile"] = time.perf_counter() - t1

    def _canonical_sapien_state(self) -> None:
        """Set SAPIEN's state to itself (CPU sim), once per control step: PhysX then derives the
        links' poses and velocities from the root pose, qpos and qvel, as ``set_state_dict`` does,
        instead of keeping those its solver integrated, which now and then differ in the last
        float32 bit (the next step then differs: qvel ~1e-8, tactile maps ~5e-7 N). The state after
        a step is then a function of ``get_state_dict()`` alone, so that a step from a restored
        state (ManiSkill's replay by env states: step, then set the recorded state) is bit-identical
        to the recorded one. About 0.1 ms per step."""
        if not self.gpu_sim_enabled:
            self.scene.set_sim_state(self.scene.get_sim_state())

    def _before_simulation_step(self):
        """Two-way coupling: the pads' reactions of the last MPM step act during this SAPIEN
        step, on the two-way objects and, equal and opposite, on the pad links."""
        super()._before_simulation_step()
        obj_w = self._wrench
        if self._contacts.shape[1]:
            obj_w = {n: w.copy() for n, w in self._wrench.items()}
            if self.pad_coupling == "explicit":
                link_w = self._contacts[..., :6].sum(2)
                for i, name in enumerate(self._pad_links):
                    apply_wrench(self.agent.robot.links_map[name], link_w[:, i])
            else:  # the links' share goes through their drives, the two-way objects' through springs
                fold_pad_reaction(self._contacts, self._contact_friction, self._joint_contacts, self._object_springs,
                                  list(self._rigid), obj_w)
        for name, w in obj_w.items():
            apply_wrench(self._rigid[name].actor, w)

    @property
    def pad_links(self) -> list[str]:
        """Names of the links that carry pads (each once, in pad order)."""
        return list(self._pad_links)

    def pad_link_wrench(self) -> torch.Tensor:
        """[B, len(pad_links), 6] force [N] and torque [N·m] (about each link's origin, world
        frame) the pads passed to their links during the last MPM step; with
        ``pad_reaction`` it acts on the links during the next SAPIEN step."""
        self._ensure_cosims()
        out = np.stack([self._pad_link_wrenches(sim) for sim in self.cosims])
        return torch.as_tensor(out, dtype=torch.float32, device=self.device)

    def _pad_link_wrenches(self, sim: GaussTacSim) -> np.ndarray:
        """[len(pad_links), 6] of one co-simulator (see :meth:`pad_link_wrench`)."""
        return np.array([np.concatenate(sim.link_wrench(link)) for link in self._pad_links])

    def object_wrench(self, name: str) -> torch.Tensor:
        """[B, 6] force [N] and torque [N·m] (about the object origin) the pads exerted on
        MPM rigid object ``name`` during the last step."""
        if name not in self._rigid:
            raise ConfigError(f"unknown MPM object {name!r}; objects: {sorted(self._rigid)}")
        out = [np.concatenate(sim.object_wrench(name)) for sim in self.cosims]
        return torch.as_tensor(np.array(out), dtype=torch.float32, device=self.device)

    # ------------------------------------------------------------------ step / obs
    def step(self, action):
        """ManiSkill's step, after checking ``action`` (:meth:`_checked_action`): an array of
        real numbers (integers are cast to float32) of shape ``[A]`` or ``[B, A]``, finite."""
        action = self._checked_action(action)
        t0 = time.perf_counter()
        self.step_timing.update(mpm=0.0, tactile=0.0, render=0.0)
        out = super().step(action)
        for hand in self._joint_contacts:  # the controller's drives again, as users and the next action see them
            hand.restore()
        total = time.perf_counter() - t0
        self.step_timing["total"] = total
        self.step_timing["physics"] = total - sum(self.step_timing[k] for k in ("mpm", "tactile", "render"))
        return out

    def _checked_action(self, action):
        """``action`` as a float32 tensor on the env's device, or a ``ConfigError`` naming
        what is wrong (:func:`~gausstac_maniskill.task_checks.check_action`). Accepted: real
        numbers (int and float dtypes; integers cast to float32) of shape ``[A]`` or ``[B, A]``,
        A the control mode's action size, all finite. ``None`` and dict actions pass unchanged."""
        if action is None or isinstance(action, dict):
            return action
        task = self.spec.id if self.spec else self._env_id()
        return check_action(task, action, getattr(self._orig_single_action_space, "shape", None), self.num_envs,
                            self.control_mode, self.device)

    def get_obs(self, info=None, unflattened: bool = False):
        """ManiSkill's observation plus ``obs["tactile"]``. Every leaf is a copy: no tensor of
        it shares memory with the env's state (task targets, the tactile maps
        :meth:`tactile` keeps, the controller's targets) or with another observation, so a
        kept observation never changes with later resets or steps."""
        obs = super().get_obs(info, unflattened=True)
        if self._obs_mode != "none":
            t0 = time.perf_counter()
            self._ensure_cosims()
            self.tactile_sensor.capture(optical=self._obs_mode != "state")
            tactile = self.tactile_sensor.get_obs()
            if self._obs_mode == "state":  # a flat state vector: maps flattened to [B, H*W(*2)]
                tactile = {p: {k: v.reshape(v.shape[0], -1) for k, v in m.items()} for p, m in tactile.items()}
            obs["tactile"] = tactile
            self.step_timing["tactile"] = self.step_timing.get("tactile", 0.0) + time.perf_counter() - t0
        obs = copied(obs)
        return obs if unflattened else self._flatten_raw_obs(obs)

    def _get_obs_sensor_data(self, apply_texture_transforms: bool = True) -> dict:
        t0 = time.perf_counter()
        out = super()._get_obs_sensor_data(apply_texture_transforms)
        self.step_timing["render"] = self.step_timing.get("render", 0.0) + time.perf_counter() - t0
        return out

    def tactile(self) -> dict:
        """``{pad: {"depth": [B, H, W] m, "shear": [B, H, W, 2] m, "force": [B, H, W] N,
        "pressure": [B, H, W] Pa}}`` of the last MPM step, float32 on the env's device: read
        for every env in one launch, once per step (kept until the state changes)."""
        self._ensure_cosims()
        if self._tactile_maps is None:
            self._tactile_maps = self._batch.tactile(self.device)
        return self._tactile_maps

    def pad_force(self, pad: str) -> torch.Tensor:
        """[B] total normal contact force [N] on ``pad`` (sum of its force map)."""
        if pad not in self.pad_names:
            raise ConfigError(f"unknown pad {pad!r}; pads: {self.pad_names}")
        return self.tactile()[pad]["force"].sum(dim=(1, 2))

    # ------------------------------------------------------------------ state
    def _get_task_state(self) -> dict[str, torch.Tensor]:
        """Task variables that SAPIEN's state does not hold (targets, progress), [B, ...]
        tensors; part of ``get_state_dict`` so that replay by env states is exact."""
        return {}

    def _set_task_state(self, state: dict, env_idx) -> None:
        """Restore :meth:`_get_task_state` (rows ``env_idx``)."""

    def get_state_dict(self):
        """ManiSkill's state plus ``state["task"]`` (the task's variables, the two-way wrenches and
        pad contacts acting next: :func:`~gausstac_maniskill.tactile_env.task_state_leaves`) and,
        with ``record_mpm_state``, ``state["gausstac"]`` (every co-simulator's flat state)."""
        state = super().get_state_dict()
        task = task_state_leaves(self._get_task_state(), self._wrench, self._contacts, self.num_envs)
        if task:
            state["task"] = task
        if self.record_mpm_state and self.cosims and not self._cosim_stale:
            state["gausstac"] = stacked_flat_states(self.cosims)
        return state

    def set_state_dict(self, state: dict, env_idx: torch.Tensor = None):
        """SAPIEN state, then the task's variables, then the co-simulators: restored from
        ``state["gausstac"]`` when present (exact), otherwise rebuilt at rest."""
        state = batch_state(state)
        mpm = state.get("gausstac")
        sim_state = {k: v for k, v in state.items() if k not in ("gausstac", "task")}
        super().set_state_dict(sim_state, env_idx)
        rows = torch.arange(self.num_envs) if env_idx is None else torch.as_tensor(common.to_numpy(env_idx))
        task, wrench, contacts = split_task_state(state.get("task", {}), rows, self.num_envs, self._get_task_state)
        if task:
            self._set_task_state(task, rows)  # first: soft objects are built from task variables
        if mpm is None:
            self._build_cosims()  # at rest, from the poses just set
        else:
            self._ensure_cosims()
            load_flat_states(self.cosims, mpm, rows, self.num_envs)
            self._tactile_maps = None
        for name, w in wrench.items():
            if name in self._wrench:
                self._wrench[name][rows.numpy()] = w.double().numpy()
        if contacts is not None and self._contacts.size:
            self._contacts[rows.numpy()] = contacts.double().numpy().reshape((len(rows),) + self._contacts.shape[1:])
