"""GaussTacSim: the co-simulator of one scene — soft pads on hand links, objects, Gaussians.

Data flows one way: link poses (from SAPIEN or MuJoCo) → :meth:`GaussTacSim.step`
→ pad and object solvers → tactile maps (and, via :meth:`render`, the Gaussian
Splatting camera).

Pads: by default (``pad_solver="auto"``) solved at equilibrium each step with linear
cut-cell FEM (:mod:`gausstac_maniskill.pads.fem`, no pseudo-mass, no particles in the MPM
world); optionally MLS-MPM particles of the world relaxed quasi-statically with a pseudo-mass
(``pad_solver="mpm"``, :mod:`gausstac_maniskill.pads.mpm`). The scene holds one pad solver per
kind (:class:`~gausstac_maniskill.pads.interface.PadSolver`) and only orchestrates: it moves the
links and objects, tells each solver which of its pads an object nears, steps the world and
has the solvers solve and read out their pads. Soft objects are MPM particles with their
physical mass; rigid objects are SDF colliders.

Pads whose bounding sphere is farther than ``sleep_margin`` from every object sleep: an
equilibrium pad is then at rest; an MPM pad once it has relaxed (no particle more than
``REST_TOLERANCE`` from its rest place on the link, or no longer moving) is put exactly on its
rest shape, is not simulated, costs nothing and reports zero maps, carried rigidly by its link,
and wakes up as soon as an object comes near. A pad never falls asleep deformed.

Default numerics are chosen for robot control steps (20–100 Hz): grid spacing 1 mm
(pad particles every 0.5 mm). Units: SI.
"""
from __future__ import annotations

from typing import Callable, Mapping, Sequence

import numpy as np
import torch

from ..config import Material, PadSolverSettings, PadSpec, SolverSettings
from ..errors import ConfigError
from ..geometry.colliders import Collider
from ..mpm import MPMWorld
from ..pads import EquilibriumPads, MPMPads, PadSolver
from ..pads.fem import add_contact
from ..pads.mpm import REST_TOLERANCE
from ..tactile import Pad, pad_geometry
from ..tactile.readout import TactileReadout
from ..transforms import as_pose_matrix
from ..urdf import default_hand_urdf
from .rows import SceneRows
from .sleep import update_sleep
from .state import SceneState

__all__ = ["GaussTacSim", "REST_TOLERANCE"]


class GaussTacSim(SceneRows, SceneState):
    """Soft pads on rigid links (at equilibrium by default, or MLS-MPM) plus rigid and soft
    objects in one MPM world.

    Args:
        pads: pad descriptions (see :func:`gausstac_maniskill.tactile.allegro_pad_specs`).
        link_poses: initial world pose (4x4) of every pad link, by link name.
        urdf: URDF the pad links' collision meshes come from (default: ManiSkill's Allegro).
        settings: solver settings (default :class:`~gausstac_maniskill.config.SolverSettings`).
        pad_settings: how the pads are solved (:class:`~gausstac_maniskill.config.PadSolverSettings`:
            solver, FEM model and precompute, contact surface, sleep margin); default: its defaults.
        world, env: build the scene as env ``env`` of a shared (batched) :class:`MPMWorld`
            instead of a world of its own (:class:`~gausstac_maniskill.batch.BatchedCosim`
            does this); its links and groups are named ``env{env}/<name>`` there. A scene in
            a shared world does not step it (the batch does): use the batch's ``step``.
        pad_solver, fem_model, fem_precompute, pad_surface, sleep_margin: shorthand for
            ``pad_settings=PadSolverSettings(solver=pad_solver, fem_model=..., fem_precompute=...,
            surface=pad_surface, sleep_margin=...)`` (not together with ``pad_settings``):
        sleep_margin: distance [m] between a pad and the nearest object below which it wakes.
        pad_surface: where colliders touch a pad: ``"mesh"`` (default) on the link mesh
            itself, each surface particle's contact radius its distance below the mesh
            (:attr:`Pad.contact_radius`), the same surface at every resolution;
            ``"particles"`` half a particle spacing beyond its outermost particles, a
            staircase that on a curved pad stands up to half a spacing off the mesh,
            differently at each resolution. Held force at the default dx = 1 mm against
            dx = 0.5 mm of the same mode (``bench pad --curve``): mesh +5.5 %
            (5 mm sphere) / −3.6 % (plate); particles +10.9 % / +6.3 %, and at dx = 0.5 mm the
            particle staircase still reads 12 % (sphere) / 4 % (plate) above the mesh surface.
        pad_solver: ``"auto"`` (default): ``"fem"`` (with ``fem_model="neo_hookean"``: ``"mpm"``
            once a soft object is added before the pads touched anything; ``pad_surface=
            "particles"``: ``"mpm"``); :attr:`pad_solver` says which.
            ``"mpm"``: the pads are MPM particles relaxed with a pseudo-mass,
            in contact with rigid and soft objects. ``"fem"``: each awake pad is solved at
            equilibrium after every step (:class:`~gausstac_maniskill.fem.sensor.EquilibriumPad`:
            cube elements on the particle lattice, cut by the layer's curved surface and bond,
            no locking as ν → 0.5, no pseudo-mass), against
            the rigid objects within reach (each surface point meets the nearest) and under the
            push of soft objects (``fem_model="linear"``): each pad's link mesh is a collider of
            the MPM world that they meet, shaped as the pad was last solved, and their contact
            impulses on it load the pad (:meth:`add_soft_object`). The splat camera draws
            these pads from their solution; in a batch (:class:`~gausstac_maniskill.batch.BatchedCosim`)
            every env solves its own, with one body per pad.
            A pad's first approach to an object builds its body (:meth:`prepare_pads` does it
            at once), and the first time on a machine its compliance and its maps' response
            (one sweep, kept under ``~/.cache/gausstac_maniskill``).
        fem_model: the ``"fem"`` pads' material model, ``"linear"`` (fast; small strain) or
            ``"neo_hookean"`` (finite strain; much slower per step; a
            step whose iterations stall with the layer's cut cells finite is solved with them
            linear, with a :class:`~gausstac_maniskill.errors.SimulationWarning`:
            :meth:`~gausstac_maniskill.fem.QuasiStaticBody.solve`).
        fem_precompute: the ``"fem"`` pads' compliance among all their surface points computed
            when a pad's body is built (True), or each point's when it first touches (False);
            default (None): in full when it takes at most
            :data:`~gausstac_maniskill.fem.sensor.PRECOMPUTE_BYTES` (256 MiB: the default
            dx = 1 mm), else point by point with a
            :class:`~gausstac_maniskill.errors.CostWarning`. The full compliance costs memory
            and a one-time build per pad shape and makes each press step far cheaper than
            point by point (``bench patch --pad-solver fem`` measures both).
    """

    def __init__(self, pads: Sequence[PadSpec], link_poses: Mapping[str, np.ndarray], *,
                 urdf: str | None = None, settings: SolverSettings | None = None,
                 pad_settings: PadSolverSettings | None = None, world: MPMWorld | None = None, env: int = 0,
                 pad_solver: str | None = None, fem_model: str | None = None, fem_precompute: bool | None = None,
                 pad_surface: str | None = None, sleep_margin: float | None = None):
        self.pad_settings = _pad_settings(pad_settings, pad_solver=pad_solver, fem_model=fem_model,
                                          fem_precompute=fem_precompute, pad_surface=pad_surface,
                                          sleep_margin=sleep_margin)
        self.urdf = urdf or default_hand_urdf()
        if world is None:
            self.settings = settings or SolverSettings()
            self.world = MPMWorld(self.settings)
        else:
            self.settings = world.settings
            self.world = world
        self.env = int(env)
        self.shared = world is not None
        self._prefix = f"env{self.env}/" if self.shared else ""
        self.sleep_margin = self.pad_settings.sleep_margin
        #: "auto": finite-strain pads (fem_model="neo_hookean") turn to the MPM's if a soft object
        #: is added before they touch anything
        self._auto = self.pad_settings.solver == "auto"
        #: the pads' solver now, ``"fem"`` or ``"mpm"`` (``pad_solver="auto"`` resolved)
        self.pad_solver = self.pad_settings.initial_solver
        #: one pad solver per kind (:class:`~gausstac_maniskill.pads.interface.PadSolver`), by kind
        self.solvers: dict[str, PadSolver] = {"fem": EquilibriumPads(self, self.pad_settings),
                                              "mpm": MPMPads(self, self.pad_settings)}
        self.pads: dict[str, Pad] = {}
        self._link_pose: dict[str, np.ndarray] = {}
        self._objects: dict[str, int] = {}
        self._soft: dict[str, str] = {}
        names = [p.name for p in pads]
        if len(set(names)) != len(names):
            raise ConfigError(f"pad names must be unique, got {names}")
        h = self.settings.particle_spacing
        for spec in pads:
            if spec.link not in link_poses:
                raise ConfigError(f"link_poses has no pose for pad link {spec.link!r} "
                                  f"(given: {sorted(link_poses)})")
            pad = pad_geometry(spec, self.urdf, h, self.settings.dx)
            T = as_pose_matrix(link_poses[spec.link], f"link_poses[{spec.link!r}]")
            if not self.world.has_link(self._w(spec.link)):
                self.world.add_link(self._w(spec.link), T, env=self.env)
            self.pads[spec.name] = pad
            self._link_pose[spec.link] = T
            self.solvers[self.pad_solver].add(spec.name)
        self._link_pose = {k: as_pose_matrix(v, f"link_poses[{k!r}]") for k, v in link_poses.items()}
        self._maps: dict[str, dict[str, torch.Tensor]] = {}
        self._update_sleep()

    def _w(self, name: str) -> str:
        """The world's name of this scene's link or group ``name``."""
        return self._prefix + name

    def world_name(self, name: str) -> str:
        """The world's name of this scene's link or group ``name`` (``env{env}/name`` in a shared world)."""
        return self._prefix + name

    def link_pose(self, link: str) -> np.ndarray:
        """[4, 4] world pose [m] of link ``link`` at the end of the current step."""
        return self._link_pose[link]

    @property
    def rigid_objects(self) -> Mapping[str, int]:
        """Rigid object name -> the index of its collider in the world."""
        return self._objects

    @property
    def soft_objects(self) -> Mapping[str, str]:
        """The soft objects, by name (each its world group's, :meth:`world_name`)."""
        return self._soft

    def pad_solver_of(self, pad: str) -> PadSolver:
        """The solver (:class:`~gausstac_maniskill.pads.interface.PadSolver`) of pad ``pad``."""
        name = self._pad(pad).name
        for solver in self.solvers.values():
            if name in solver:
                return solver
        raise ConfigError(f"pad {name!r} has no solver")  # (never: every pad has one)

    @property
    def pad_solve_time(self) -> float:
        """Wall time [s] of the last step's equilibrium solves (0 without equilibrium pads)."""
        return self.solvers["fem"].solve_time

    def group(self, name: str):
        """The world's :class:`~gausstac_maniskill.mpm.solver.Group` of MPM pad or soft object
        ``name`` (its particle rows ``start:stop`` in the world's arrays; equilibrium pads have
        none: :meth:`particle_rows`)."""
        return self.world.group(self._w(name))

    # ------------------------------------------------------------------ objects
    def add_link(self, name: str, pose) -> None:
        """A rigid link of this scene that is not a pad link (e.g. the holder a soft object
        is glued to: ``add_soft_object(..., link=name)``); ``pose`` 4x4 [m]."""
        self.world.add_link(self._w(name), pose, env=self.env)

    def object_positions(self, name: str) -> np.ndarray:
        """[N, 3] world positions [m] of soft object ``name``'s particles after the last step."""
        return self.world.positions(self._soft_group(name))

    def object_deformation_gradients(self, name: str) -> np.ndarray:
        """[N, 3, 3] deformation gradients of soft object ``name``'s particles after the last step."""
        return self.world.deformation_gradients(self._soft_group(name))

    def _soft_group(self, name: str) -> str:
        """The world's group name of soft object ``name`` (clear error if there is none)."""
        if name not in self._soft:
            raise ConfigError(f"unknown soft object {name!r}; soft objects: {sorted(self._soft)}")
        return self._w(name)

    def add_rigid_object(self, name: str, collider: Collider) -> None:
        """A rigid object (SDF collider) the pads can touch; move it with :meth:`set_object_pose`."""
        if name in self._objects or name in self._soft:
            raise ConfigError(f"object {name!r} already exists")
        self._objects[name] = self.world.add_collider(collider, env=self.env)
        self._update_sleep()

    def add_soft_object(self, name: str, positions, material: Material, **kwargs) -> None:
        """A deformable object made of MPM particles at world ``positions`` [N, 3] (m);
        ``kwargs`` go to :meth:`MPMWorld.add_group`. It is a body of its own (velocity
        field 1, the pads' is 0): MPM pads touch it through a frictional contact rule
        (``settings.soft_friction``), and their contact force maps read that contact.

        Pads solved at equilibrium (``pad_solver="fem"``, ``fem_model="linear"``) meet it as a
        rigid collider each (their link mesh, friction ``settings.soft_friction``) whose SDF is
        lowered by the pad's last solved normal displacement, so the object meets the pad
        where the pad was pushed in, one step behind (a staggered coupling: the object's
        push in a step loads the pad at its end, and the pad's shape from it is what the
        object meets next). The push is the reaction to the object's particles' contact
        impulses with that collider, each at the pad's surface point nearest the particle,
        added to the rigid objects' contact by superposition (the pad is linear). With
        ``pad_solver="auto"`` the pads stay at equilibrium (``fem_model="neo_hookean"``: a soft
        object added before they touched anything turns them into MPM pads)."""
        if name in self._objects or name in self._soft or name in self.pads:
            raise ConfigError(f"object {name!r} already exists")
        fem = self.solvers["fem"]
        if len(fem) and not fem.meet_soft_object(name, self._auto):
            self._to_mpm_pads()
        kwargs.setdefault("field", 1)
        if isinstance(kwargs.get("link"), str):
            kwargs["link"] = self._w(kwargs["link"])
        self.world.add_group(self._w(name), positions, material, env=self.env, **kwargs)
        self._soft[name] = name
        self._update_sleep()

    def _to_mpm_pads(self) -> None:
        """``pad_solver="auto"`` with ``fem_model="neo_hookean"`` meets a soft object: the pads,
        untouched so far, become MPM particles: groups of the world, asleep at rest on their
        links (they wake when an object nears)."""
        mpm = self.solvers["mpm"]
        for name in self.solvers["fem"].clear():
            mpm.add(name, asleep=True)
        self.pad_solver = "mpm"
        self._maps = {}

    def set_object_pose(self, name: str, pose) -> None:
        """Target pose (4x4) of a rigid object at the end of the next step."""
        if name not in self._objects:
            raise ConfigError(f"unknown rigid object {name!r}; objects: {sorted(self._objects)}")
        self.world.set_collider_pose(self._objects[name], pose)

    def object_wrench(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Reaction force [N] and torque [N·m] (about its origin) the pads and soft objects
        exerted on rigid object ``name`` during the last step (for two-way coupling)."""
        if name not in self._objects:
            raise ConfigError(f"unknown rigid object {name!r}; objects: {sorted(self._objects)}")
        f, tau = self.world.collider_wrench(self._objects[name])
        origin = self.world.colliders[self._objects[name]].pose[:3, 3]
        for solver in self.solvers.values():  # what the world does not hold
            f, tau = solver.object_wrench(name, origin, f, tau)
        return f, tau

    def link_wrench(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        """Reaction force [N] and torque [N·m] (about the link origin, world frame) that the
        pads bound to hand link ``link`` passed to it during the last step: what objects
        pushed on them, through a massless layer (for two-way coupling of the hand; equal
        and opposite to the rigid objects' share of :meth:`object_wrench`)."""
        f, tau = self.world.link_wrench(self._w(link))
        for solver in self.solvers.values():  # what the world does not hold
            f, tau = solver.link_wrench(link, f, tau)
        return f, tau

    def link_contacts(self, link: str) -> dict[str | None, np.ndarray]:
        """Per object that hand link ``link``'s pads touched in the last step, ``[7]``: the
        force [N] and torque [N·m] (about the link origin, world frame) it passed to the
        link, and the pads' indentation [m] (deepest displacement of a touching pad particle
        from its rest place, along its push). Keys: rigid object names; ``None`` for soft
        objects (the other velocity field). Objects not touched are left out; the values
        sum to :meth:`link_wrench`."""
        rows = self.world.link_contacts(self._w(link))
        names = {i: n for n, i in self._objects.items()}
        out = {names.get(i): r for i, r in enumerate(rows) if (i in names or i == len(rows) - 1) and np.any(r[:6])}
        for solver in self.solvers.values():  # what the world does not hold
            for name, row in solver.link_contacts(link).items():
                add_contact(out, name, row)
        return out

    # ------------------------------------------------------------------ stepping
    def step(self, link_poses: Mapping[str, np.ndarray], dt: float,
             object_poses: Mapping[str, np.ndarray] | None = None) -> dict[str, dict[str, torch.Tensor]]:
        """Advance ``dt`` seconds with the links moving to ``link_poses`` (name → 4x4,
        must include every pad link) and objects to ``object_poses``; return tactile maps."""
        if self.shared:
            raise ConfigError("GaussTacSim.step: this scene is one env of a shared world; step the batch "
                              "(BatchedCosim.step), which steps every env in the same launches")
        self.begin_step(link_poses, object_poses)
        self.world.step(dt)
        self.end_step()
        return self.tactile()

    def begin_step(self, link_poses: Mapping[str, np.ndarray],
                   object_poses: Mapping[str, np.ndarray] | None = None) -> None:
        """First half of :meth:`step`: set the link and object targets, wake or put pads
        to sleep (the world is then stepped once for every scene in it)."""
        for spec in (p.spec for p in self.pads.values()):
            if spec.link not in link_poses:
                raise ConfigError(f"step: link_poses has no pose for pad link {spec.link!r}")
        poses = {link: as_pose_matrix(T, f"link_poses[{link!r}]") for link, T in link_poses.items()}
        self.world.set_link_poses({self._w(k): T for k, T in poses.items() if self.world.has_link(self._w(k))})
        self.after_link_poses(poses, object_poses)

    def after_link_poses(self, link_poses: Mapping[str, np.ndarray],
                         object_poses: Mapping[str, np.ndarray] | None = None) -> None:
        """:meth:`begin_step` once the world holds the link targets (a batch sets every env's
        at once): keep every link's pose ``link_poses`` (name → checked 4x4 [m]; the renderer
        poses the whole hand), move the objects, wake or put pads to sleep."""
        self._link_pose.update(link_poses)
        for solver in self.solvers.values():
            solver.after_link_poses()
        for name, T in (object_poses or {}).items():
            self.set_object_pose(name, T)
        self._update_sleep()

    def end_step(self) -> None:
        """Second half of :meth:`step`, after the world stepped: solve the equilibrium pads
        (``pad_solver="fem"``) at the step's end poses, forget the last maps."""
        for solver in self.solvers.values():
            solver.end_step()
        self._maps = {}
        self._posed = None

    def prepare_pads(self) -> None:
        """Build the equilibrium pads' bodies now (``pad_solver="fem"``): assemble each pad's
        stiffness and compute or load its surface compliance
        (:class:`~gausstac_maniskill.fem.sensor.EquilibriumPad`), which otherwise happens in
        the first step that brings an object within ``sleep_margin`` of the pad. The
        compliance and its maps' response (the default binning's, in the same sweep) are
        computed the first time on a machine, then read from the disk cache. Does nothing
        for MPM pads."""
        for solver in self.solvers.values():
            solver.prepare()

    def _update_sleep(self) -> None:
        """Wake the pads that an object nears over the coming step, put the others to sleep
        (:func:`.sleep.update_sleep`)."""
        update_sleep(self)


    # ------------------------------------------------------------------ rendering
    def attach_gaussians(self, hand=None, hand_links: Sequence[str] = (), objects=None, hand_lod=None,
                         closed_links: Sequence[str] = ()) -> None:
        """Give the scene its 3D Gaussians (see :class:`gausstac_maniskill.render.SceneGaussians`).

        Call it with the pads and soft objects at rest (before stepping into contact):
        their soft Gaussians are placed on the current particles.

        Args:
            hand: rigid hand Gaussians, link-local (``splat.asset.load_hand_gaussians(folder)[0]``).
            hand_links: their link names (``links.json["link_names"]``); every one of them
                must then be in the ``link_poses`` passed to :meth:`step`.
            objects: rigid object name -> Gaussians in the object frame.
            hand_lod: ``(fine spacing [m], ((spacing [m], hand Gaussians), ...))``, coarser
                levels finest first (``splat.asset.load_hand_lod``): a camera whose pixels at the
                hand are as wide as a level's splats draws that level instead
                (:class:`gausstac_maniskill.render.Detail`).
            closed_links: hand links whose Gaussians lie on closed surfaces with their normals
                pointing out (``links.json["closed_links"]``): the splat camera skips those
                facing away (see :class:`gausstac_maniskill.render.SceneGaussians`).
        """
        from ..render import SceneGaussians

        self._scene = SceneGaussians(self, hand, hand_links, objects, hand_lod, closed_links)
        self._posed = None

    def add_render_layer(self, layer) -> None:
        """Add Gaussians the co-simulator does not move (a captured scene, captured objects
        on SAPIEN actors: a :class:`gausstac_maniskill.render.RigidLayer`) to the splat scene;
        they are splatted in the same pass as the hand and depth-sorted with it. Call
        :meth:`attach_gaussians` first."""
        if not self.has_gaussians:
            raise ConfigError("GaussTacSim.add_render_layer: call attach_gaussians(...) first")
        self._scene.add_layer(layer)
        self._posed = None

    @property
    def has_gaussians(self) -> bool:
        """Whether :meth:`attach_gaussians` gave the scene something to render."""
        return getattr(self, "_scene", None) is not None

    @property
    def splat_scene(self):
        """The :class:`gausstac_maniskill.render.SceneGaussians` of :meth:`attach_gaussians`, or None."""
        return getattr(self, "_scene", None)

    def posed_scene(self, soft: Callable[[], torch.Tensor] | None = None):
        """The splat scene (a :class:`gausstac_maniskill.render.PosedScene`) at the current state,
        posed once per step whatever the number of cameras; ``soft``: a function returning the
        frames [P', 3, 4] of the particles the soft Gaussians ride on, when the caller reads
        them for many scenes at once (a batch), called only if this scene needs posing."""
        if not self.has_gaussians:
            raise ConfigError("GaussTacSim.render: call attach_gaussians(...) first")
        if getattr(self, "_posed", None) is None:
            self._posed = self._scene.posed(soft() if soft is not None else None)
        return self._posed

    def render(self, viewmats, Ks, width: int, height: int, **kwargs):
        """Render the scene with the splat camera: ``viewmats`` [C, 4, 4] world-to-camera
        (OpenCV convention), ``Ks`` [C, 3, 3] pixel intrinsics; returns a ``RenderOutput``
        (``rgb`` [C, H, W, 3], ``depth`` [C, H, W] m, ``alpha`` [C, H, W])."""
        return self.posed_scene().render(torch.as_tensor(viewmats, dtype=torch.float32),
                                  torch.as_tensor(Ks, dtype=torch.float32), width, height, **kwargs)

    # ------------------------------------------------------------------ readout
    def is_awake(self, pad: str) -> bool:
        """Whether pad ``pad`` is being simulated this step."""
        name = self._pad(pad).name
        return self.pad_solver_of(name).awake[name]

    def _pad(self, name: str) -> Pad:
        if name not in self.pads:
            raise ConfigError(f"unknown pad {name!r}; pads: {sorted(self.pads)}")
        return self.pads[name]

    def tactile(self) -> dict[str, dict[str, torch.Tensor]]:
        """``{pad: {"depth": [H, W] m, "shear": [H, W, 2] m, "force": [H, W] N,
        "pressure": [H, W] Pa}}`` of the last step (float32, on the Taichi arch's device); a
        sleeping pad reads all zeros. One launch reads every pad on the device
        (:class:`~gausstac_maniskill.tactile.readout.TactileReadout`)."""
        if not self._maps:
            maps = {}
            for solver in self.solvers.values():
                maps.update(solver.tactile())
            self._maps = {name: maps[name] for name in self.pads}
        return self._maps

    def pad_contact_forces(self, pad: str) -> np.ndarray:
        """[N, 3] world contact force [N] on each of ``pad``'s particles in the last step (from
        rigid objects, and for a pad at equilibrium soft objects too; zero where none)."""
        name = self._pad(pad).name
        return self.pad_solver_of(name).contact_forces(name)

    def readout(self) -> TactileReadout:
        """The :class:`~gausstac_maniskill.tactile.readout.TactileReadout` of this scene's MPM pads."""
        return self.solvers["mpm"].readout()

    def pad_slots(self) -> list[tuple[str, str]]:
        """Per pad, the world's names of its particle group and its link."""
        return [(self._w(name), self._w(pad.spec.link)) for name, pad in self.pads.items()]

    def pad_pressure_force(self, pad: str) -> float:
        """Normal force [N] on ``pad`` estimated from its stress (pressure map × taxel area);
        unlike :meth:`pad_normal_force` it includes contacts with soft objects."""
        p = self._pad(pad)
        px, py = p.spec.layout.pitch
        return float(self.tactile()[p.name]["pressure"].sum()) * px * py

    def pad_stress_force(self, pad: str) -> np.ndarray:
        """Total force [N] that contacts exert on ``pad``, read from its stress by virtual
        work, in the sensor frame (x along the finger, y across, z out of the pad; pressing
        gives a negative z). Rigid and soft contacts alike.

        With a test field φ = 1 − d/h over the soft layer (d the rest depth below the pad
        surface, h the layer thickness; φ = 1 on the contact surface, 0 at the bond), the
        weak form of equilibrium gives ∫ σ ∇φ dV = ∫ φ t dA = the contact force, since the
        free surface carries no traction. Quadrature over the soft particles:
        f = Σ_p V0_p J_p σ_p F_p⁻ᵀ N_p / h, N_p the rest outward normal
        (:meth:`MPMWorld.virtual_work_force`). Exact at
        equilibrium up to quadrature, for any contact position on the layer; unlike the
        pressure map it does not assume the load is carried along the sensor axis.
        A pad solved at equilibrium (``pad_solver="fem"``) sums its elements' internal nodal
        forces off the bond instead: equal to the contact force at equilibrium by construction.
        """
        p = self._pad(pad)
        if not self.is_awake(p.name):
            return np.zeros(3)
        return self.pad_solver_of(p.name).stress_force(p.name)

    def pad_normal_force(self, pad: str) -> float:
        """Total normal contact force [N] on ``pad`` in the last step (sum of its force map)."""
        return float(self.tactile()[self._pad(pad).name]["force"].sum())

    def pad_particles(self, pad: str) -> tuple[np.ndarray, np.ndarray]:
        """Current world positions [N, 3] and deformation gradients [N, 3, 3] of a pad's particles.

        A sleeping pad is not simulated; it is reported carried rigidly by its link."""
        name = self._pad(pad).name
        return self.pad_solver_of(name).particles(name)



def _pad_settings(settings: PadSolverSettings | None, **loose) -> PadSolverSettings:
    """``settings``, or the :class:`PadSolverSettings` of the loose options given (GaussTacSim's
    keyword names; None: the default); giving both is a :class:`ConfigError`."""
    given = {k: v for k, v in loose.items() if v is not None}
    if settings is None:
        fields = {"pad_solver": "solver", "pad_surface": "surface"}
        return PadSolverSettings(**{fields.get(k, k): v for k, v in given.items()})
    if not isinstance(settings, PadSolverSettings):
        raise ConfigError(f"GaussTacSim(pad_settings={settings!r}) must be a PadSolverSettings")
    if given:
        raise ConfigError(f"GaussTacSim: give pad_settings or the loose pad options ({sorted(given)}), not both")
    return settings
