"""Scenes that several benchmarks and tests build: the product's index pad with its rigid
indenters, the indenters as signed distances for the pads at equilibrium, and the MPM layer
bonded to a rigid base (the thin-layer set-up), with the press protocols run on them.

SI units throughout (m, s, N, Pa). The analytic solutions they are judged by are in
:mod:`gausstac_maniskill.reference`."""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass

import numpy as np

# ---------------------------------------------------------------------------- the index pad
INDEX = "link_3.0_tip"  # the index tip's pad link (Allegro)
SPHERE_RADIUS = 5e-3  # m
FRICTION = 0.5  # Coulomb, the indenters'
SLIDE = 2e-3  # m, along sensor x
GAP = 0.2e-3  # m, indenter clearance at rest
DT = 0.05  # s, control step
AREA_FORCE = 1e-3  # N, a taxel above this force is in contact
#: the pad link's world pose: identity rotation (the particle lattice aligned with the MPM grid), 10 cm up
LINK_POSE = np.array([[1.0, 0, 0, 0.0], [0, 1.0, 0, 0.0], [0, 0, 1.0, 0.1], [0, 0, 0, 1.0]])
MAPS = ("depth", "shear", "force")


@dataclass
class Protocol:
    """Control steps of each stage: ramp per depth, slide, and hold (measured)."""

    press: int = 3
    slide: int = 4
    hold: int = 3


FULL = Protocol(3, 4, 3)  # the pad benchmark's protocol


def index_spec(thickness: float | None = None):
    """The product's default PadSpec of the index tip (optionally another soft thickness [m])."""
    from ..tactile import allegro_pad_specs

    kw = {} if thickness is None else {"thickness": float(thickness)}
    return next(s for s in allegro_pad_specs(**kw) if s.link == INDEX)


def indenter_pose(kind: str, W: np.ndarray, z: float, x: float = 0.0) -> np.ndarray:
    """World pose of indenter ``kind`` whose surface point nearest the pad is at sensor
    coordinates (x, 0, z) [m]; ``W`` is the sensor frame's world pose (4x4)."""
    from ..transforms import make_pose

    p = W[:3, :3] @ np.array([x, 0.0, z]) + W[:3, 3]
    if kind == "plate":  # half-space solid along +z_sensor: its local z points at the pad
        return make_pose(p, W[:3, :3] @ np.diag([1.0, -1.0, -1.0]))
    return make_pose(p + W[:3, 2] * SPHERE_RADIUS, W[:3, :3])


def indenter_collider(kind: str, pose: np.ndarray, friction: float):
    """The rigid indenter ``kind`` ("plate": a :class:`HalfSpace`; "sphere": a :class:`Sphere` of
    radius :data:`SPHERE_RADIUS`) at world pose ``pose`` (4x4, :func:`indenter_pose`) with Coulomb
    ``friction``."""
    from ..geometry import HalfSpace, Sphere

    if kind == "plate":
        return HalfSpace(pose=pose, friction=friction)
    return Sphere(radius=SPHERE_RADIUS, pose=pose, friction=friction)


def _contact_area(sim, pad) -> float:
    """Projected area [m²] of the pad particles with a contact force: their rest sensor
    coordinates binned on the particle lattice (h × h cells)."""
    f = sim.pad_contact_forces(INDEX)
    s = pad.sensor_coords()[np.linalg.norm(f, axis=1) > 0]
    if not len(s):
        return 0.0
    cells = np.unique(np.round((s[:, :2] - pad.sensor_coords()[0, :2]) / pad.spacing).astype(np.int64), axis=0)
    return len(cells) * pad.spacing ** 2


def make_sim(dx: float, indenter: str, thickness: float | None = None, friction: float = FRICTION,
             mass_scaling: float | None = None, pad_surface: str = "mesh", patch_radius=False,
             cfl: float | None = None, pad_solver: str = "mpm", fem_model: str = "linear",
             fem_precompute: bool | None = None):
    """The index-pad scene: the index pad at :data:`LINK_POSE` in a :class:`GaussTacSim` with
    :class:`~gausstac_maniskill.config.SolverSettings` (grid spacing ``dx`` [m], optionally another pseudo-mass
    factor ``mass_scaling``, ``patch_radius`` [m] or None (False: the default's) and Courant
    number ``cfl``;
    ``pad_surface``, ``pad_solver``, ``fem_model`` and ``fem_precompute`` as in :class:`GaussTacSim`) and
    ``indenter``
    ("plate" | "sphere") 0.2 mm clear of its apex. Returns (sim, W): W the sensor frame's
    world pose (4x4)."""
    from ..config import SolverSettings
    from ..cosim import GaussTacSim

    extra = {} if mass_scaling is None else {"mass_scaling": float(mass_scaling)}
    if patch_radius is not False:
        extra["patch_radius"] = patch_radius
    if cfl is not None:
        extra["cfl"] = float(cfl)
    sim = GaussTacSim([index_spec(thickness)], {INDEX: LINK_POSE}, settings=SolverSettings(dx=dx, **extra),
                      pad_surface=pad_surface, pad_solver=pad_solver, fem_model=fem_model,
                      fem_precompute=fem_precompute)
    W = LINK_POSE @ sim.pads[INDEX].sensor_frame
    sim.prepare_pads()  # the equilibrium pad's factor and compliance: set-up, not a step's cost
    sim.add_rigid_object("indenter", indenter_collider(indenter, indenter_pose(indenter, W, GAP), friction))
    return sim, W


def press_pad(dx: float, indenter: str, depths, thickness: float | None = None, protocol: Protocol = FULL,
              friction: float = FRICTION, bar=None, mass_scaling: float | None = None,
              pad_surface: str = "mesh", patch_radius=False, cfl: float | None = None, pad_solver: str = "mpm",
              fem_model: str = "linear", fem_precompute: bool | None = None) -> dict:
    """Press then slide ``indenter`` ("plate" | "sphere") on the index pad at grid spacing ``dx`` [m]
    (``protocol.slide == 0``: press only); ``mass_scaling``: the pads' pseudo-mass factor
    (default: :class:`~gausstac_maniskill.config.SolverSettings`); ``patch_radius`` [m] the active patch (None: off,
    False: the default's); ``cfl`` the Courant number (default: the settings'); ``pad_solver``
    ``"fem"`` solves the pad at equilibrium instead (with ``fem_model``, ``fem_precompute``): its ``step_ms`` is
    the equilibrium solve's wall time plus the MPM world's (which then holds no particles).

    Returns ``{"dx", "indenter", "particles", "soft", "substeps", "step_ms", "build_s",
    "phases": [...]}``; each phase (``"press"`` / ``"slide"`` at depth ``d`` [m]) holds
    hold-step means of ``Fn``, ``Ft``, ``Fy``, ``F_map`` [N], ``F_spread`` (max−min)/mean
    of Fn, ``Fn_end``, ``F_stress_end`` and ``F_pressure_end`` (means over the second half of the
    hold: the settled end), ``area_taxel``, ``area_particle`` [m²], ``peak_depth`` [m] and ``maps``
    (``depth`` [H, W] m, ``shear`` [H, W, 2] m, ``force`` [H, W] N, numpy).
    """
    t0 = time.perf_counter()
    sim, W = make_sim(dx, indenter, thickness, friction, mass_scaling, pad_surface, patch_radius, cfl,
                      pad_solver, fem_model, fem_precompute)
    pad = sim.pads[INDEX]
    spec = pad.spec
    build_s = time.perf_counter() - t0
    lay = spec.layout
    taxel_area = lay.pitch[0] * lay.pitch[1]
    walls, subs, active = [], [], []

    def step(z: float, x: float):
        maps = sim.step({INDEX: LINK_POSE}, DT, {"indenter": indenter_pose(indenter, W, z, x)})[INDEX]
        walls.append(sim.world.last_step.wall_time + sim.pad_solve_time)
        subs.append(sim.world.last_step.substeps)
        active.append(sim.world.last_step.active_particles)
        if bar is not None:
            bar.update(1)
        F = W[:3, :3].T @ sim.object_wrench("indenter")[0]  # on the indenter, sensor axes
        return F, {k: maps[k].cpu().numpy().astype(np.float64) for k in MAPS}

    def hold(phase: str, d: float, z: float, x: float) -> dict:
        Fs, ms, areas, Fstress = [], [], [], []
        first = len(walls)
        for _ in range(protocol.hold):
            F, m = step(z, x)
            Fs.append(F)
            ms.append(m)
            areas.append(_contact_area(sim, pad))
            Fstress.append((-sim.pad_stress_force(INDEX)[2], sim.pad_pressure_force(INDEX)))
        Fs = np.array(Fs)
        maps = {k: np.mean([m[k] for m in ms], axis=0) for k in MAPS}
        Fn = float(Fs[:, 2].mean())
        end = len(Fs) // 2
        stress, pressure = np.array(Fstress).T
        held_walls, held_subs = walls[first + end:], subs[first + end:]
        return dict(phase=phase, d=d, Fn=Fn, Ft=float(-Fs[:, 0].mean()), Fy=float(Fs[:, 1].mean()),
                    F_map=float(maps["force"].sum()), F_stress=float(stress.mean()), F_pressure=float(pressure.mean()),
                    Fn_end=float(Fs[end:, 2].mean()), F_stress_end=float(stress[end:].mean()),
                    F_pressure_end=float(pressure[end:].mean()),
                    wall_end=1e3 * float(np.mean(held_walls)), substeps_end=float(np.mean(held_subs)),
                    F_spread=float(np.ptp(Fs[:, 2]) / Fn) if Fn else float("nan"),
                    area_taxel=float((maps["force"] > AREA_FORCE).sum() * taxel_area),
                    area_particle=float(np.mean(areas)), peak_depth=float(maps["depth"].max()), maps=maps)

    step(GAP, 0.0)  # at rest: JIT compile and settle, not timed
    walls.clear()
    subs.clear()
    active.clear()
    phases, z = [], GAP
    for d in depths:
        for k in range(protocol.press):
            step(z + (-d - z) * (k + 1) / protocol.press, 0.0)
        z = -d
        phases.append(hold("press", d, z, 0.0))
        if not protocol.slide:
            continue
        pressed = sim.state_dict()
        for k in range(protocol.slide):
            step(z, SLIDE * (k + 1) / protocol.slide)
        phases.append(hold("slide", d, z, SLIDE))
        sim.load_state_dict(pressed)
    return dict(dx=dx, indenter=indenter, pad_solver=pad_solver, spacing=pad.spacing,
                mass_scaling=sim.settings.mass_scaling, particles=pad.num_particles,
                soft=int((~pad.kinematic).sum()), patch_radius=sim.settings.patch_radius, cfl=sim.settings.cfl,
                active=float(np.mean(active)),
                substeps=float(np.mean(subs)), step_ms=1e3 * float(np.mean(walls)), build_s=build_s,
                thickness=spec.thickness, phases=phases)


def index_pad(size: float):
    """The index pad (:func:`index_spec`) built on its own, for the pads at equilibrium: particle
    spacing = element edge ``size`` [m], on the MPM grid of 2·size; its link frame is the world's."""
    from ..cosim import default_hand_urdf
    from ..tactile.pad import build_pad, pad_mesh

    spec = index_spec()
    with warnings.catch_warnings():  # a 1 mm lattice is a 2 mm MPM grid's: the warning is about the MPM
        warnings.simplefilter("ignore")
        return build_pad(spec, pad_mesh(spec, default_hand_urdf()), size, 2.0 * size)


# ---------------------------------------------------------------------------- indenters as signed distances
def paraboloid(R: float, apex) -> callable:
    """The layer solution's indenter as an ``sdf`` for :meth:`QuasiStaticBody.solve`: a
    paraboloid of radius R [m] with its apex at ``apex`` [3] m, opening along +z, in
    small-displacement form: φ(x) = apex_z + r²/(2R) − x_z with r measured at the points
    given and the normal −z (only u_z closes the gap)."""
    apex = np.asarray(apex, float)

    def sdf(x):
        r2 = ((x[:, :2] - apex[:2]) ** 2).sum(1)
        return apex[2] + r2 / (2.0 * R) - x[:, 2], np.tile([0.0, 0.0, -1.0], (len(x), 1))

    return sdf


def sphere(R: float, centre) -> callable:
    """A rigid sphere of radius R [m] centred at ``centre`` [3] m as an ``sdf`` for
    :meth:`QuasiStaticBody.solve` (exact distance and outward normal)."""
    centre = np.asarray(centre, float)

    def sdf(x):
        v = x - centre
        r = np.linalg.norm(v, axis=1)
        return r - R, v / r[:, None]

    return sdf


# ---------------------------------------------------------------------------- the bonded MPM layer
#: the thin-layer set-up: Young's modulus [Pa], Poisson ratio, density [kg/m³], thickness [m] (the
#: product pad's layer), the contact radii a/h of its points, and the depth δ/h of every point
E_LAYER = 3e5
NU_LAYER = 0.45
RHO_LAYER = 1100.0
H_LAYER = 4e-3
A_OVER_H = (0.3, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)
STRAIN = 0.1  # δ/h of every point


def layer_world(h: float, dx: float, nu: float, half_width: float, offset: float = 0.5, fbar: bool = True,
                bond: str = "surface", pressure: str = "explicit"):
    """MPM world with a quarter layer [0, W]² × [z_top − h, z_top] (W = ``half_width`` [m], thickness
    ``h`` [m], grid ``dx`` [m], :data:`E_LAYER`, Poisson ratio ``nu``, :data:`RHO_LAYER`) on a 2-cell
    kinematic base bound to the fixed link "base", with slip walls on x = 0 and y = 0 (forces ×4).
    z_top is chosen so that the bond plane z_top − h lies ``offset`` cells above a node
    plane (default half a cell between node planes); ``fbar``, ``bond``, ``pressure``: SolverSettings.
    Returns ``(world, group, z_top)``."""
    from ..config import Material, SolverSettings
    from ..geometry import box_particles
    from ..mpm import MPMWorld

    settings = SolverSettings(dx=dx, gravity=(0.0, 0.0, 0.0), max_substeps=1_000_000, fbar=fbar, bond=bond,
                              pressure=pressure, mass_scaling=1.0)
    hp = settings.particle_spacing
    if abs(h / hp - round(h / hp)) > 1e-6:
        raise ValueError(f"layer thickness h={h} m must be a multiple of the particle spacing {hp} m")
    z_bond = (math.floor(-h / dx) + offset) * dx
    z_top = z_bond + h
    world = MPMWorld(settings)
    world.add_link("base", np.eye(4))
    pts = box_particles([0.0, 0.0, z_bond - 2 * dx], [half_width, half_width, z_top], hp)
    group = world.add_group("layer", pts, Material(E=E_LAYER, nu=nu, density=RHO_LAYER), link="base",
                            kinematic=pts[:, 2] < z_bond)
    world.add_slip_wall(0, 0.0, "+")
    world.add_slip_wall(1, 0.0, "+")
    return world, group, z_top


def press_collider(world, collider, pose_at, depth: float, relax_rate: float, ramp: float, hold: float,
                   steps_per_relax: int = 4) -> tuple[float, float, int, float]:
    """Quasi-static press: move ``collider`` to ``pose_at(depth)`` [m] over ``ramp``/ζ seconds and hold
    ``hold``/ζ (ζ = ``relax_rate`` [1/s], ``steps_per_relax`` control steps per 1/ζ); returns
    (mean reaction z over the last quarter of the hold, relative change from the
    quarter before, substeps, solver wall time)."""
    dt = 1.0 / (relax_rate * steps_per_relax)
    n_ramp, n_hold = int(ramp * steps_per_relax), max(int(hold * steps_per_relax), 8)
    fz, substeps, wall = [], 0, 0.0
    for k in range(n_ramp + n_hold):
        world.set_collider_pose(collider, pose_at(depth * min(1.0, (k + 1) / n_ramp)))
        info = world.step(dt)
        substeps, wall = substeps + info.substeps, wall + info.wall_time
        if k >= n_ramp:
            fz.append(world.collider_wrench(collider)[0][2])
    q = len(fz) // 4
    last, before = float(np.mean(fz[-q:])), float(np.mean(fz[-2 * q:-q]))
    return last, abs(last - before) / max(abs(last), 1e-30), substeps, wall


def effective_thickness(h: float, dx: float, nu: float = NU_LAYER, strain: float = 0.05,
                        ramp: float = 20.0, hold: float = 40.0, offset: float = 0.5, bond: str = "surface",
                        pressure: str = "explicit") -> float:
    """Effective thickness [m] of the simulated bonded layer: a 2×2-cell column of the
    same lattice (bond plane ``offset`` cells above a node plane; ``bond``:
    SolverSettings.bond), slip walls on all four sides, compressed by a frictionless plate
    by δ = ``strain``·h (uniaxial strain). h_eff is the thickness whose Neo-Hookean
    uniaxial strain δ/h_eff gives the measured stress F/A
    (:func:`~gausstac_maniskill.reference.uniaxial_stress`);
    equal to h for a perfectly rigid bond at the right place."""
    from scipy.optimize import brentq

    from ..geometry import HalfSpace
    from ..reference import uniaxial_stress

    W = 2 * dx
    world, group, z_top = layer_world(h, dx, nu, W, offset=offset, bond=bond, pressure=pressure)
    world.add_slip_wall(0, W, "-")
    world.add_slip_wall(1, W, "-")
    flip = np.diag([1.0, -1.0, -1.0])  # solid side of the half-space up

    def pose_at(d):
        T = np.eye(4)
        T[:3, :3], T[2, 3] = flip, z_top - d
        return T

    plate = world.add_collider(HalfSpace(pose=pose_at(0.0), friction=0.0))
    F, _, _, _ = press_collider(world, plate, pose_at, strain * h, group.relaxation, ramp, hold)
    sigma = F / (W * W)
    eps = brentq(lambda e: uniaxial_stress(e, E_LAYER, nu) - sigma, 1e-9, 0.9)
    return strain * h / eps


def run_point(R: float, d: float, h: float = H_LAYER, dx: float = 1e-3, nu: float = NU_LAYER,
              half_width: float | None = None, ramp: float = 10.0, hold: float = 20.0,
              bond: str = "surface", fbar: bool = True, pressure: str = "explicit") -> dict:
    """Press a frictionless sphere of radius R [m] to depth d [m] into the bonded layer
    (:func:`layer_world`, quarter W = max(3a, a + 4h) wide unless ``half_width``, a = √(Rd)) with
    :func:`press_collider` (``ramp``, ``hold`` in relaxation times); returns the measured force
    F_sim = 4·(reaction) beside the references of :mod:`gausstac_maniskill.reference` (forces in N,
    lengths in m; F_dimitriadis None beyond its χ range)."""
    from ..geometry import Sphere
    from ..reference import CHI_MAX_DIMITRIADIS, dimitriadis_bonded, hertz_force, layer_force, sneddon
    from ..transforms import make_pose

    t0 = time.perf_counter()
    a = math.sqrt(R * d)
    W = half_width or max(3 * a, a + 4 * h)
    W = math.ceil(W / dx - 1e-9) * dx
    world, group, z_top = layer_world(h, dx, nu, W, bond=bond, fbar=fbar, pressure=pressure)

    def pose_at(depth):
        return make_pose([0.0, 0.0, z_top + R - depth])

    sphere = world.add_collider(Sphere(radius=R, pose=pose_at(0.0), friction=0.0))
    fz, settle, substeps, solver_wall = press_collider(world, sphere, pose_at, d, group.relaxation, ramp, hold)
    E_star = E_LAYER / (1 - nu ** 2)
    chi = a / h
    F_layer, a_layer = layer_force(E_LAYER, nu, R, d, h)
    return dict(R=R, d=d, h=h, dx=dx, nu=nu, a=a, a_over_h=chi, chi=chi, a_over_dx=a / dx, half_width=W,
                particles=world.num_particles, substeps=substeps, settle=settle,
                wall=time.perf_counter() - t0, solver_wall=solver_wall, F_sim=4.0 * fz,
                F_dimitriadis=float(dimitriadis_bonded(E_LAYER, nu, R, d, h)) if chi <= CHI_MAX_DIMITRIADIS else None,
                F_layer=F_layer, a_layer=a_layer, F_hertz=float(hertz_force(E_star, R, d)),
                F_sneddon=sneddon(E_star, R, d)[0])
