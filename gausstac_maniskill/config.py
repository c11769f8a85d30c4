"""Descriptions (immutable inputs) of the simulation, in SI units.

Like MuJoCo's model/data split, these dataclasses describe *what* is simulated;
the solver's Taichi fields hold the mutable state. Every field is validated on
construction and a :class:`~gausstac_maniskill.errors.ConfigError` names the
field at fault.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from .errors import ConfigError

__all__ = ["Material", "SolverSettings", "PadSolverSettings", "SensorLayout", "PadSpec", "MODELS"]

#: Constitutive models understood by the MPM solver.
MODELS = ("neo_hookean", "fixed_corotated", "foam")


def _finite(name: str, value: float) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}={value!r} is not a number") from None
    if not math.isfinite(value):
        raise ConfigError(f"{name}={value!r} must be finite")
    return value


@dataclass(frozen=True)
class Material:
    """An isotropic solid: a pad's silicone, or a soft object's MPM particles.

    The defaults are the product's pad silicone, Smooth-On Dragon Skin 10 (platinum-cure
    silicone rubber, Shore 10A). Its data sheet gives a 100 % modulus of 151 kPa (22 psi) and a
    specific gravity of 1.07; a neo-Hookean fit of that point, σ_eng = μ(λ − λ⁻²) = 1.75 μ at
    λ = 2, gives μ = 86.7 kPa and E = 3μ ≈ 0.26 MPa. Cured silicone is nearly incompressible
    (bulk modulus about 1 GPa, ν ≈ 0.4999); ν = 0.48 is the modelling choice, free of locking in
    both pad solvers.

    Attributes:
        E: Young's modulus [Pa], > 0. Silicone pads: 0.1–2 MPa; sponge: 5–50 kPa.
        nu: Poisson's ratio [-], in (-1, 0.5). Up to 0.499 (near-incompressible) is
            supported without locking (``SolverSettings.fbar``); each step toward 0.5
            costs substeps, as the P-wave speed grows as √(λ + 2μ). 0.5 exactly is
            rejected (infinite bulk modulus).
        density: mass density [kg/m^3], > 0.
        model: ``"neo_hookean"`` (compressible Neo-Hookean, the default),
            ``"fixed_corotated"`` (Stomakhin et al. 2012), or ``"foam"``.
        yield_compression: ``foam`` only. Critical compressive principal strain
            θc: a singular value of the elastic deformation gradient below
            ``1 - θc`` flows plastically (the sponge is crushed and stays so).
        yield_stretch: ``foam`` only. Critical stretch θs (singular values above
            ``1 + θs`` flow plastically).
        hardening: ``foam`` only. ξ in ``k(Jp) = exp(ξ (1 - Jp))``: plastic
            compaction (Jp < 1) stiffens the foam, as cells collapse.

    The ``foam`` model is multiplicative elastoplasticity F = Fe·Fp with a
    fixed-corotated elastic law on Fe, whose singular values are clamped to
    [1-θc, 1+θs] after each substep (the excess goes to Fp, Stomakhin et al. 2013),
    and Lamé parameters scaled by k(Jp), Jp = det Fp.
    """

    E: float = 2.6e5
    nu: float = 0.48
    density: float = 1070.0
    model: str = "neo_hookean"
    yield_compression: float = 0.10
    yield_stretch: float = 0.05
    hardening: float = 3.0

    def __post_init__(self) -> None:
        E = _finite("Material.E", self.E)
        nu = _finite("Material.nu", self.nu)
        rho = _finite("Material.density", self.density)
        if E <= 0:
            raise ConfigError(f"Material.E={self.E!r} Pa must be > 0")
        if not (-1.0 < nu < 0.5):
            raise ConfigError(
                f"Material.nu={self.nu!r} must lie in (-1, 0.5); 0.5 is perfectly "
                "incompressible (infinite bulk modulus) — use 0.49 for rubber-like silicone")
        if rho <= 0:
            raise ConfigError(f"Material.density={self.density!r} kg/m^3 must be > 0")
        if self.model not in MODELS:
            raise ConfigError(f"Material.model={self.model!r} is not one of {MODELS}")
        for name in ("yield_compression", "yield_stretch"):
            v = _finite(f"Material.{name}", getattr(self, name))
            if not (0.0 < v < 1.0):
                raise ConfigError(f"Material.{name}={v!r} must lie in (0, 1)")
        if _finite("Material.hardening", self.hardening) < 0:
            raise ConfigError(f"Material.hardening={self.hardening!r} must be >= 0")
        object.__setattr__(self, "E", E)
        object.__setattr__(self, "nu", nu)
        object.__setattr__(self, "density", rho)

    @property
    def mu(self) -> float:
        """Shear modulus μ = E / (2(1+ν)) [Pa]."""
        return self.E / (2.0 * (1.0 + self.nu))

    @property
    def lam(self) -> float:
        """First Lamé parameter λ = Eν / ((1+ν)(1-2ν)) [Pa]."""
        return self.E * self.nu / ((1.0 + self.nu) * (1.0 - 2.0 * self.nu))

    @property
    def wave_speed(self) -> float:
        """P-wave speed c = √((λ + 2μ)/ρ) [m/s], which bounds the explicit time step."""
        return math.sqrt((self.lam + 2.0 * self.mu) / self.density)

    @property
    def plane_strain_modulus(self) -> float:
        """E* = E / (1 - ν²) [Pa] against a rigid indenter (Hertz)."""
        return self.E / (1.0 - self.nu ** 2)


@dataclass(frozen=True)
class SolverSettings:
    """Numerical settings of the MPM co-simulator.

    The defaults are the product's, for fingertip pads at robot control rates (20–100 Hz):
    dx = 1 mm (pad particles every 0.5 mm), the MPM pads' pseudo-mass ×1000 (the wave speed of a
    0.3 MPa silicone drops from 32 to 1 m/s; free soft objects keep their physical mass), no
    absolute damping (pads relax relative to their link), gravity along −z.

    Attributes:
        dx: grid spacing [m]. Particles are seeded ``particles_per_axis`` per cell
            per axis, so the particle spacing is ``dx / particles_per_axis``.
        particles_per_axis: particles per cell along each axis (2 → 8 per cell).
        cfl: Courant number C in Δt ≤ C·dx / (c + |v|max); 0 < C ≤ 1.
        max_substeps: the most substeps one control step may take. If the CFL
            bound needs more, :class:`~gausstac_maniskill.errors.SimulationError`
            says so and what to change (never silently unstable).
        mass_scaling: pseudo-mass s ≥ 1 of *quasi-static* groups (pads bound to a
            link, solved by dynamic relaxation): their density is multiplied by s, so
            their wave speed and the substep count drop by √s, and their motion relative
            to the link is damped towards equilibrium. Free groups (no kinematic
            particles) always keep their physical mass, and weight is always physical.
        hold_scaling: a quasi-static group's pseudo-mass is multiplied by this factor
            (≥ 1; 1: off) while it holds: once it has settled (its particles move slower than
            ``hold_speed`` relative to its link) and for as long as nothing moves its boundary
            (its link and its env's colliders move their surfaces slower than
            ``hold_speed / 5``, no soft body awake in its env). The equilibrium of dynamic
            relaxation does not depend on the pseudo-mass, so a held contact keeps its force
            (within 0.2 % over ten held steps on the Allegro pad, ``bench pad --curve``) at
            √hold_scaling fewer substeps (4× at the default 16); the first motion of its
            boundary brings the default pseudo-mass back for that step. ``GaussTacEnv`` sets it
            to 1 where the pads' reaction moves SAPIEN bodies (``pad_reaction``, two-way objects).
        hold_speed: the speed [m/s] below which a pad counts as settled (see ``hold_scaling``).
        damping: viscous velocity damping rate [1/s] applied on the grid
            (v ← v·exp(-damping·Δt)); 0 = none. Helps reach quasi-static states.
        gravity: gravitational acceleration [m/s^2] in the world frame.
        fbar: F-bar anti-locking (default on): stresses use the grid-smoothed volume
            change J̄ (one per node) instead of each particle's own, so nearly
            incompressible silicone (ν → 0.5) does not lock; ``False`` is plain MLS-MPM.
        soft_friction: Coulomb friction coefficient between bodies of different velocity
            fields (a pad and a soft object; see ``MPMWorld.add_group``'s ``field``).
        grid_margin: empty cells kept around the active particles' bounding box.
        max_grid_cells: safety limit on the active grid's cell count.
        patch_radius: the active patch [m] (``None``: off). Only the part of a pad whose
            rest place lies within this distance of a collider is simulated; a shell
            around it is held where it is and the rest rides rigidly with its link
            (:mod:`gausstac_maniskill.mpm.patch`), so the cost follows the contact, not
            the pad's size. The truncation error is measured by ``bench patch``.
        bond: where a layer is held by its kinematic core. ``"surface"`` (default): at
            the bond surface itself, between grid nodes (ghost nodes,
            ``kernels.bond_ghosts``); ``"nodes"``: at the pinned node planes nearest to
            it (the layer's stiffness then varies by up to ±11 % at 4 cells with how
            the grid lies; kept for comparison, ``bench thinlayer --bond nodes``).
        pressure: how the volume term λ ln J of Neo-Hookean materials is integrated.
            ``"explicit"`` (default): with the rest of the stress, F-bar against locking; the
            substep follows the P-wave speed √((λ+2μ)/ρ), which has no bound as ν → 0.5.
            ``"implicit"``: one value per grid cell, solved backward Euler in every substep
            (``kernels.pressure_solve``), so the substep follows √(2μ/ρ) whatever ν (3.6×
            fewer substeps at ν = 0.48, 16× at ν = 0.499). Other models stay explicit.
            On the 4 mm bonded layer at dx = 1 mm it reads −0.9 % against theory at ν = 0.499
            in 360 substeps, where F-bar is +10.9 % in 4320; at ν ≤ 0.48 it is softer than
            F-bar (−9.6 % at 0.48) and, its CG iterations
            costing ~4 explicit substeps, not faster: the choice for ν ≥ 0.49.
        pressure_iterations: the most conjugate-gradient iterations of that solve per
            substep (it stops earlier once the residual fell by 10⁴).
    """

    dx: float = 1.0e-3
    particles_per_axis: int = 2
    cfl: float = 0.4
    max_substeps: int = 5000
    mass_scaling: float = 1000.0
    hold_scaling: float = 16.0
    hold_speed: float = 1.0e-4
    damping: float = 0.0
    gravity: tuple = (0.0, 0.0, -9.81)
    fbar: bool = True
    soft_friction: float = 0.5
    grid_margin: int = 3
    max_grid_cells: int = 8_000_000
    patch_radius: float | None = None
    bond: str = "surface"
    pressure: str = "explicit"
    pressure_iterations: int = 8

    def __post_init__(self) -> None:
        if _finite("SolverSettings.dx", self.dx) <= 0:
            raise ConfigError(f"SolverSettings.dx={self.dx!r} m must be > 0")
        if int(self.particles_per_axis) != self.particles_per_axis or not (1 <= self.particles_per_axis <= 4):
            raise ConfigError(f"SolverSettings.particles_per_axis={self.particles_per_axis!r} must be an integer in 1..4")
        cfl = _finite("SolverSettings.cfl", self.cfl)
        if not (0.0 < cfl <= 1.0):
            raise ConfigError(f"SolverSettings.cfl={self.cfl!r} must lie in (0, 1]")
        if int(self.max_substeps) != self.max_substeps or self.max_substeps < 1:
            raise ConfigError(f"SolverSettings.max_substeps={self.max_substeps!r} must be a positive integer")
        if _finite("SolverSettings.mass_scaling", self.mass_scaling) < 1.0:
            raise ConfigError(f"SolverSettings.mass_scaling={self.mass_scaling!r} must be >= 1")
        if _finite("SolverSettings.hold_scaling", self.hold_scaling) < 1.0:
            raise ConfigError(f"SolverSettings.hold_scaling={self.hold_scaling!r} must be >= 1 (1: off)")
        if _finite("SolverSettings.hold_speed", self.hold_speed) <= 0.0:
            raise ConfigError(f"SolverSettings.hold_speed={self.hold_speed!r} m/s must be > 0")
        if _finite("SolverSettings.damping", self.damping) < 0.0:
            raise ConfigError(f"SolverSettings.damping={self.damping!r} 1/s must be >= 0")
        g = tuple(self.gravity)
        if len(g) != 3:
            raise ConfigError(f"SolverSettings.gravity={self.gravity!r} must have 3 components")
        object.__setattr__(self, "gravity", tuple(_finite("SolverSettings.gravity", v) for v in g))
        if _finite("SolverSettings.soft_friction", self.soft_friction) < 0.0:
            raise ConfigError(f"SolverSettings.soft_friction={self.soft_friction!r} must be >= 0")
        if not isinstance(self.fbar, bool):
            raise ConfigError(f"SolverSettings.fbar={self.fbar!r} must be True or False")
        if int(self.grid_margin) != self.grid_margin or self.grid_margin < 2:
            raise ConfigError(f"SolverSettings.grid_margin={self.grid_margin!r} must be an integer >= 2")
        if int(self.max_grid_cells) != self.max_grid_cells or self.max_grid_cells < 1000:
            raise ConfigError(f"SolverSettings.max_grid_cells={self.max_grid_cells!r} must be an integer >= 1000")
        if self.bond not in ("surface", "nodes"):
            raise ConfigError(f"SolverSettings.bond={self.bond!r} must be 'surface' or 'nodes'")
        if self.pressure not in ("explicit", "implicit"):
            raise ConfigError(f"SolverSettings.pressure={self.pressure!r} must be 'explicit' or 'implicit'")
        if int(self.pressure_iterations) != self.pressure_iterations or not (1 <= self.pressure_iterations <= 200):
            raise ConfigError(f"SolverSettings.pressure_iterations={self.pressure_iterations!r} must be an integer "
                              "in 1..200")
        if self.patch_radius is not None and _finite("SolverSettings.patch_radius", self.patch_radius) <= 0.0:
            raise ConfigError(f"SolverSettings.patch_radius={self.patch_radius!r} m must be > 0 (or None: off)")

    @property
    def particle_spacing(self) -> float:
        """Distance between seeded particles [m]."""
        return self.dx / self.particles_per_axis


@dataclass(frozen=True)
class PadSolverSettings:
    """How a scene's pads are solved: which solver, its material model and surface, and when a
    pad sleeps. One object travels from the task to the pad solvers unchanged.

    Attributes:
        solver: ``"auto"`` (default): ``"fem"``, except ``"mpm"`` with ``surface="particles"``,
            and with ``fem_model="neo_hookean"`` ``"mpm"`` once a soft object is added before the
            pads touched anything; ``"fem"``: each awake pad solved at equilibrium after every
            step (:class:`~gausstac_maniskill.fem.sensor.EquilibriumPad`, no pseudo-mass);
            ``"mpm"``: MLS-MPM particles relaxed with a pseudo-mass.
        fem_model: the equilibrium pads' material model, ``"linear"`` (small strain, fast) or
            ``"neo_hookean"`` (finite strain, much slower per step).
        fem_precompute: the equilibrium pads' compliance among all their surface points computed
            when a pad's body is built (True), or each point's when it first touches (False);
            None (default): in full when it takes at most
            :data:`~gausstac_maniskill.fem.sensor.PRECOMPUTE_BYTES`.
        surface: where colliders touch a pad: ``"mesh"`` (default) on the link mesh itself,
            ``"particles"`` half a particle spacing beyond its outermost particles (MPM pads only).
        sleep_margin: distance [m] between a pad and the nearest object below which it wakes,
            >= 0.
    """

    solver: str = "auto"
    fem_model: str = "linear"
    fem_precompute: bool | None = None
    surface: str = "mesh"
    sleep_margin: float = 5.0e-3

    def __post_init__(self) -> None:
        if self.surface not in ("particles", "mesh"):
            raise ConfigError(f"pad_surface={self.surface!r} must be 'particles' or 'mesh'")
        if self.solver not in ("auto", "mpm", "fem"):
            raise ConfigError(f"pad_solver={self.solver!r} must be 'auto', 'mpm' or 'fem'")
        if self.fem_model not in ("linear", "neo_hookean"):
            raise ConfigError(f"pad_solver={self.solver!r}, fem_model={self.fem_model!r}: use pad_solver 'auto', "
                              "'mpm' or 'fem' and fem_model 'linear' or 'neo_hookean'")
        if self.fem_precompute not in (None, True, False):
            raise ConfigError(f"fem_precompute={self.fem_precompute!r} must be None, True or False")
        if self.solver == "fem" and self.surface != "mesh":
            raise ConfigError("pad_solver='fem' needs pad_surface='mesh' "
                              "(the equilibrium pads are touched on the link mesh)")
        margin = _finite("PadSolverSettings.sleep_margin", self.sleep_margin)
        if margin < 0.0:
            raise ConfigError(f"PadSolverSettings.sleep_margin={self.sleep_margin!r} m must be >= 0")
        object.__setattr__(self, "sleep_margin", margin)

    @property
    def initial_solver(self) -> str:
        """The pads' solver when the scene is built, ``"fem"`` or ``"mpm"`` (``"auto"`` resolved)."""
        if self.solver == "auto":
            return "fem" if self.surface == "mesh" else "mpm"
        return self.solver


@dataclass(frozen=True)
class SensorLayout:
    """A taxel grid on a pad: ``rows`` × ``cols`` cells covering ``size`` [m].

    The grid lies in the sensor frame's x–y plane (x along the finger, y across,
    z out of the pad); row index grows with y, column index with x.
    """

    rows: int = 16
    cols: int = 16
    size: tuple = (0.02, 0.02)

    def __post_init__(self) -> None:
        for name in ("rows", "cols"):
            v = getattr(self, name)
            if int(v) != v or not (1 <= v <= 1024):
                raise ConfigError(f"SensorLayout.{name}={v!r} must be an integer in 1..1024")
        size = tuple(self.size)
        if len(size) != 2:
            raise ConfigError(f"SensorLayout.size={self.size!r} must be (size_x, size_y) in metres")
        object.__setattr__(self, "size", tuple(_finite("SensorLayout.size", v) for v in size))
        if min(self.size) <= 0:
            raise ConfigError(f"SensorLayout.size={self.size!r} m must be positive")

    @property
    def pitch(self) -> tuple:
        """Taxel pitch (x, y) [m]."""
        return (self.size[0] / self.cols, self.size[1] / self.rows)


@dataclass(frozen=True)
class PadSpec:
    """A soft tactile pad on a hand link.

    The pad is the part of the link's (watertight) collision mesh that lies within
    ``cone_deg`` of ``axis`` (seen from the mesh centre) and within ``thickness`` of
    the surface: that shell is soft silicone. The next two grid cells inwards are
    bound kinematically to the link (they carry the pad); deeper material is rigid
    and not simulated.

    Attributes:
        link: name of the link the pad sits on (e.g. ``"link_3.0_tip"``).
        name: pad id used in observations; default: the link name.
        axis: outward direction of the pad centre in the link frame (Allegro: +x is palmar).
        cone_deg: half-angle [deg] of the pad region around ``axis``.
        thickness: soft layer thickness [m]. Default 4 mm: a fingertip skin of the
            GelSight/DIGIT class is 2–5 mm thick, and 4 mm spans the 4 grid cells that
            converge at the default dx = 1 mm (``tactile.pad.MIN_LAYER_CELLS``).
        material: the silicone (default :class:`Material`: Dragon Skin 10, E = 0.26 MPa, ν = 0.48).
        layout: taxel grid of the tactile maps.
        mesh: optional mesh file (link frame) overriding the URDF collision mesh.
        along: the sensor's x axis ("along the finger") in the link frame, made orthogonal
            to ``axis``; default the link's z axis (right for the Allegro's tips).
    """

    link: str
    name: str = ""
    axis: tuple = (1.0, 0.0, 0.0)
    cone_deg: float = 60.0
    thickness: float = 4.0e-3
    material: Material = field(default_factory=Material)
    layout: SensorLayout = field(default_factory=SensorLayout)
    mesh: str | None = None
    along: tuple | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.link, str) or not self.link:
            raise ConfigError(f"PadSpec.link={self.link!r} must be a link name")
        if not self.name:
            object.__setattr__(self, "name", self.link)
        a = tuple(_finite("PadSpec.axis", v) for v in self.axis)
        n = math.sqrt(sum(v * v for v in a)) if len(a) == 3 else 0.0
        if n < 1e-9:
            raise ConfigError(f"PadSpec.axis={self.axis!r} must be a non-zero 3-vector")
        object.__setattr__(self, "axis", tuple(v / n for v in a))
        if self.along is not None:
            u = tuple(_finite("PadSpec.along", v) for v in self.along)
            if len(u) != 3:
                raise ConfigError(f"PadSpec.along={self.along!r} must be a 3-vector")
            ax = self.axis
            perp = [u[i] - ax[i] * sum(u[j] * ax[j] for j in range(3)) for i in range(3)]
            m = math.sqrt(sum(v * v for v in perp))
            if m < 1e-6:
                raise ConfigError(f"PadSpec.along={self.along!r} is parallel to axis={self.axis!r}")
            object.__setattr__(self, "along", tuple(v / m for v in perp))
        c = _finite("PadSpec.cone_deg", self.cone_deg)
        if not (0 < c <= 180):
            raise ConfigError(f"PadSpec.cone_deg={self.cone_deg!r} must lie in (0, 180]")
        if _finite("PadSpec.thickness", self.thickness) <= 0:
            raise ConfigError(f"PadSpec.thickness={self.thickness!r} m must be > 0")
        if not isinstance(self.material, Material):
            raise ConfigError("PadSpec.material must be a Material")
        if not isinstance(self.layout, SensorLayout):
            raise ConfigError("PadSpec.layout must be a SensorLayout")
