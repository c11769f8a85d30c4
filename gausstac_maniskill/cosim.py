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

from .config import Material, PadSolverSettings, PadSpec, SolverSettings
from .errors import ConfigError
from .mpm import MPMWorld
from .geometry.colliders import Collider
from .pads import EquilibriumPads, MPMPads, PadSolver
from .pads.fem import add_contact
from .pads.mpm import REST_TOLERANCE
from .tactile import Pad, pad_geometry
from .tactile.readout import TactileReadout
from .transforms import as_pose_matrix, turn_angle
from .urdf import default_hand_urdf

__all__ = ["GaussTacSim", "REST_TOLERANCE"]


class GaussTacSim:
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
        """Wake pads near an object (collider or soft group), put the others to sleep.

        A pad is near when the region it sweeps over the coming step, relative to an object,
        comes within ``sleep_margin`` of that object; both move from their start poses (where
        the pad's particles are, where the collider was) to their end poses. Seen from the
        object's end pose, the pad's bounding-sphere centre travels from its start position
        (carried along with the object's motion) to its end position; the region lies inside
        spheres on that segment, at most the pad's radius apart, grown by half their spacing and
        by the centre's departure from the segment (at most each body's turn angle times the
        centre's distance from that body's origin). A pad that crosses an object within one
        step, or an object that crosses a pad, therefore wakes the pad, although both end poses
        may be clear. Soft objects are taken where their particles are."""
        soft_boxes = []
        if self._soft:
            for g in self._soft:
                x = self.world.positions(self._w(g))
                soft_boxes.append((x.min(0), x.max(0)))
        for name, pad in self.pads.items():
            T = self._link_pose[pad.spec.link]
            c_local, r = pad.bounding_sphere()
            c = T[:3, :3] @ c_local + T[:3, 3]
            S = self.world.link_pose(self._w(pad.spec.link))  # the step's start pose
            c0 = S[:3, :3] @ c_local + S[:3, 3]
            r += float(turn_angle(S, T)) * float(np.linalg.norm(c_local))
            near = False
            for idx in self._objects.values():
                col = self.world.colliders[idx]
                O0, O1 = self.world.collider_start_pose(idx), col.pose
                start = O1[:3, :3] @ (O0[:3, :3].T @ (c0 - O0[:3, 3])) + O1[:3, 3]  # c0 as the object sees it
                grown = r + float(turn_angle(O0, O1)) * float(np.linalg.norm(c0 - O0[:3, 3]))  # the object's turn
                centres, reach = _sweep(start, c, grown)
                near |= min(_distance(col, p) for p in centres) - reach < self.sleep_margin
            if soft_boxes:
                centres, reach = _sweep(c0, c, r)
                for lo, hi in soft_boxes:
                    d = float(np.linalg.norm(np.maximum(np.maximum(lo - centres, centres - hi), 0.0), axis=1).min())
                    near |= d - reach < self.sleep_margin
            self.pad_solver_of(name).set_near(name, near)

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
        from .render import SceneGaussians

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

    def particles(self, index: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """World positions [P, 3] and F [P, 3, 3] (float32) of every particle of the scene, for
        rendering: first the equilibrium pads' (pad after pad, from their solution:
        :attr:`solved_rows` rows), then every particle of the world (MPM pads, soft objects, in
        group order; row ``solved_rows + i`` is the world's particle i), sleeping pads carried by
        their links. With ``index`` ([P'] ascending rows) only those particles, [P', 3] and
        [P', 3, 3]. (The splat camera reads the world's on the device instead: :meth:`carry_rows`,
        :meth:`pad_carries`, :func:`gausstac_maniskill.mpm.gather.carried_frames`.)"""
        n, fem = self.solved_rows, self.solvers["fem"]
        if self._world_particles():
            x, F = self.world.positions(), self.world.deformation_gradients()
        else:
            x, F = np.zeros((0, 3), np.float32), np.zeros((0, 3, 3), np.float32)
        rows = np.arange(n + len(x)) if index is None else np.asarray(index)
        k = int(np.searchsorted(rows, n))  # rows[:k]: the equilibrium pads', rows[k:]: the world's
        x = np.concatenate([np.zeros((k, 3), np.float32), x if index is None else x[rows[k:] - n]])
        F = np.concatenate([np.zeros((k, 3, 3), np.float32), F if index is None else F[rows[k:] - n]])
        self.solvers["mpm"].fill_particles(rows[k:] - n, x[k:], F[k:])  # sleeping pads carried by their links
        fem.fill_particles(rows[:k], x[:k], F[:k])  # from their solution
        return x, F

    @property
    def solved_rows(self) -> int:
        """The equilibrium pads' particle count: the first rows of :meth:`particles` (the world's
        particles follow)."""
        return self.solvers["fem"].num_particles

    def particle_rows(self, name: str) -> tuple[int, int]:
        """Rows ``start:stop`` of pad or soft object ``name`` among :meth:`particles`."""
        fem = self.solvers["fem"]
        if name in fem:
            return fem.rows(name)
        g = self.group(name)
        return self.solved_rows + g.start, self.solved_rows + g.stop

    def _world_particles(self) -> int:
        """The world's particle count (every env's, in a shared world)."""
        return max((g.stop for g in self.world.groups), default=0)

    def rest_positions(self) -> np.ndarray:
        """[P, 3] float32 positions [m] of the rows of :meth:`particles` as held now, sleeping
        pads where they fell asleep (the equilibrium pads' from their solution, the world's as
        it holds them): what the splat scene binds its soft Gaussians to, at rest."""
        x = self.world.positions() if self._world_particles() else np.zeros((0, 3), np.float32)
        fem = self.solvers["fem"]
        return np.concatenate([np.zeros((0, 3), np.float32)] + [fem.particles(name)[0] for name in fem.names] + [x])

    def equilibrium_frames(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The frames of the rows ``rows`` ([P'] ascending rows of :meth:`particles`) that lie on
        pads solved at equilibrium (``pad_solver="fem"``): (their positions in ``rows`` [k],
        their frames (F | x) [k, 3, 4] float32, world frame, from :meth:`pad_particles`). The
        splat camera draws these pads with them."""
        rows = np.asarray(rows)
        return self.solvers["fem"].frames(rows[:int(np.searchsorted(rows, self.solved_rows))])

    def _carry(self, name: str) -> np.ndarray | None:
        """The rigid motion [4, 4] of pad ``name``'s link since the pad fell asleep (its particles
        stay where they were), or None while it is awake."""
        return self.pad_solver_of(name).carry(name)

    def carry_rows(self, index: np.ndarray) -> np.ndarray:
        """[P'] int32: for each row of :meth:`particles` in ``index`` ([P'] ascending), the row of
        :meth:`pad_carries` that carries it: 1 + the number of its pad, 0 for a soft object's."""
        index = np.asarray(index)
        rows = np.zeros(len(index), np.int32)
        for i, name in enumerate(self.pads):
            lo, hi = np.searchsorted(index, self.particle_rows(name))
            rows[lo:hi] = 1 + i
        return rows

    def pad_carries(self) -> np.ndarray:
        """[1 + pads, 3, 4] float32 rigid motions that move the particles to where the renderer
        draws them: row 0 the identity; row 1 + i pad i's link motion since it fell asleep
        (:meth:`_carry`), the identity while it is awake."""
        out = np.zeros((1 + len(self.pads), 3, 4), np.float32)
        out[:, :, :3] = np.eye(3)
        for i, name in enumerate(self.pads):
            D = self._carry(name)
            if D is not None:
                out[1 + i] = D[:3]
        return out

    @property
    def _state_env(self):
        """The env whose part of the world is this scene's state (None: the whole world)."""
        return self.env if self.shared else None

    def state_dict(self) -> dict:
        """Full state (MPM world, link poses, sleep flags); restore with :meth:`load_state_dict`.
        In a shared world, this env's part only: it loads into the same scene alone and back."""
        state = {"world": self.world.state_dict(env=self._state_env),
                 "link_pose": {k: v.copy() for k, v in self._link_pose.items()},
                 "awake": {name: self.is_awake(name) for name in self.pads}}
        for solver in self.solvers.values():  # what the world does not hold (the equilibrium pads' solutions)
            own = solver.state()
            if own:
                state[solver.kind] = own
        return state

    def flat_state(self) -> dict[str, np.ndarray]:
        """The state of :meth:`state_dict` as a flat dict of fixed-shape numpy arrays
        (no ``None``, no nesting), so that several identical scenes stack along a batch
        axis — the form ManiSkill's ``get_state_dict`` and ``RecordEpisode`` store. Pads
        solved at equilibrium add their last solution as ``fem{i}_*`` (i: the pad's index in
        :attr:`pads`; :meth:`EquilibriumPad.flat_state`)."""
        w = self.world.state_dict(env=self._state_env)
        out = {f"p_{k}": v for k, v in w["particles"].items()}
        n_groups = len(w["awake"])
        sleep = np.tile(np.eye(4), (n_groups, 1, 1))
        has_sleep = np.zeros(n_groups, bool)
        for i, T in enumerate(w["sleep_pose"]):
            if T is not None:
                sleep[i], has_sleep[i] = T, True
        out.update(
            link_prev=np.asarray(w["link_prev"], np.float64).reshape(-1, 4, 4),
            link_next=np.asarray(w["link_next"], np.float64).reshape(-1, 4, 4),
            link_twist=np.asarray(w["link_twist"], np.float64).reshape(-1, 6),
            collider_prev=np.asarray(w["collider_prev"], np.float64).reshape(-1, 4, 4),
            collider_pose=np.asarray(w["collider_pose"], np.float64).reshape(-1, 4, 4),
            collider_impulse=np.asarray(w["collider_impulse"], np.float64),
            pair_impulse=np.asarray(w["pair_impulse"], np.float64),
            group_awake=np.asarray(w["awake"], bool), group_sleep_pose=sleep, group_has_sleep_pose=has_sleep,
            scalars=np.array([w["time"], w["step_count"], w["vmax"], w["last_dt_ctrl"]], np.float64),
            link_pose=np.stack([self._link_pose[k] for k in sorted(self._link_pose)]),
            pad_awake=np.array([self.is_awake(k) for k in self.pads], bool),
        )
        for solver in self.solvers.values():
            out.update(solver.flat_state())
        return out

    def load_flat_state(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore a :meth:`flat_state` of a scene built the same way (bit-exact)."""
        names = sorted(self._link_pose)
        if len(state["link_pose"]) != len(names):
            raise ConfigError(f"load_flat_state: state has {len(state['link_pose'])} link poses, this scene "
                              f"tracks {len(names)} links ({names})")
        sc = np.asarray(state["scalars"], np.float64)
        world = {
            "particles": {k[2:]: np.asarray(v) for k, v in state.items() if k.startswith("p_")},
            "link_prev": list(np.asarray(state["link_prev"], np.float64)),
            "link_next": list(np.asarray(state["link_next"], np.float64)),
            "link_twist": list(np.asarray(state["link_twist"], np.float64)) if "link_twist" in state else None,
            "collider_prev": list(np.asarray(state["collider_prev"], np.float64)),
            "collider_pose": list(np.asarray(state["collider_pose"], np.float64)),
            "collider_impulse": np.asarray(state["collider_impulse"], np.float64),
            **{k: np.asarray(state[k], np.float64) for k in ("pair_impulse", "link_impulse") if k in state},
            "awake": np.asarray(state["group_awake"], bool),
            "sleep_pose": [np.asarray(T, np.float64) if h else None
                           for T, h in zip(state["group_sleep_pose"], state["group_has_sleep_pose"])],
            "time": float(sc[0]), "step_count": int(sc[1]), "vmax": float(sc[2]), "last_dt_ctrl": float(sc[3]),
        }
        self.load_state_dict({"world": world,
                              "link_pose": {k: np.asarray(T, np.float64) for k, T in zip(names, state["link_pose"])},
                              "awake": {k: bool(a) for k, a in zip(self.pads, state["pad_awake"])}})
        for solver in self.solvers.values():
            solver.load_flat_state(state)

    def load_state_dict(self, state: dict) -> None:
        """Restore a :meth:`state_dict` of a scene built the same way (bit-exact)."""
        self.world.load_state_dict(state["world"], env=self._state_env)
        self._link_pose = {k: v.copy() for k, v in state["link_pose"].items()}
        for solver in self.solvers.values():
            solver.awake.update({name: state["awake"][name] for name in solver.names})
            solver.load_state(state.get(solver.kind, {}))
        self._maps = {}
        self._posed = None


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


def _sweep(a: np.ndarray, b: np.ndarray, radius: float) -> tuple[np.ndarray, float]:
    """Spheres that hold a sphere of ``radius`` [m] moved along the segment a -> b: centres
    at most ``radius`` apart on it ([n + 1, 3]) and their radius, grown by half the spacing."""
    length = float(np.linalg.norm(b - a))
    n = max(1, int(np.ceil(length / max(radius, 1e-9))))
    return a + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a), radius + 0.5 * length / n


def _distance(collider: Collider, point: np.ndarray) -> float:
    """Signed distance [m] from ``point`` to ``collider`` (exact for analytic shapes, a
    bounding-sphere lower bound for meshes), in numpy: cheap enough for every step."""
    from .geometry import colliders as col

    T = collider.pose
    q = (point - T[:3, 3]) @ T[:3, :3]
    if collider.kind == col.SPHERE:
        return float(np.linalg.norm(q) - collider.radius)
    if collider.kind == col.BOX:
        d = np.abs(q) - np.asarray(collider.half_extents)
        return float(np.linalg.norm(np.maximum(d, 0.0)) + min(d.max(), 0.0))
    if collider.kind == col.CAPSULE:
        z = np.clip(q[2], -collider.half_length, collider.half_length)
        return float(np.linalg.norm(q - [0.0, 0.0, z]) - collider.radius)
    if collider.kind == col.HALFSPACE:
        return float(q[2])
    lo, hi = collider.mesh.bounds
    return float(np.linalg.norm(np.maximum(np.maximum(lo - q, q - hi), 0.0)))
