"""How an MPM world steps (:class:`WorldStepper`, part of
:class:`~gausstac_maniskill.mpm.solver.MPMWorld`): the substep count from the CFL bound, the
hold of settled quasi-static groups, the active patch, the substep launches, health checks
and torn layers, and the wrenches summed after a control step."""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass

import numpy as np

from .. import backend, environment
from ..errors import ConfigError, SimulationError, SimulationWarning
from ..transforms import turn_angle
from . import kernels as K
from .materials import cell_pressure
from .model import _collider_radius
from .state import Group
from .patch import bind_in_place, carry_rigidly, groups_in_contact, rest_gap
from .state import _STATE_FIELDS


@dataclass
class StepInfo:
    """What one control step did: substeps, substep length [s], wall time [s]."""

    substeps: int
    dt_substep: float
    wall_time: float
    active_particles: int
    grid_cells: int


def atomic_scatter() -> bool:
    """How the kernels scatter particles to the grid: with atomic adds, one thread per
    particle, on CUDA (a GPU needs thousands of threads); by slab colouring, atomic-free and
    bit-reproducible, on the CPU. ``GAUSSTAC_SCATTER=atomic|slabs`` overrides (benchmarks)."""
    mode = environment.read("GAUSSTAC_SCATTER")
    if mode not in ("", "atomic", "slabs"):
        raise ConfigError(f"GAUSSTAC_SCATTER={mode!r} must be 'atomic' or 'slabs' (or unset)")
    return mode == "atomic" if mode else backend.current_arch() == "cuda"


def _twists(a: np.ndarray, b: np.ndarray, dt: float) -> np.ndarray:
    """[N, 6] (v_origin, ω) [m/s, rad/s] of the uniform motions from poses a [N, 4, 4] to
    poses b in dt seconds (world frame; the slerp/lerp interpolation of the substeps has
    exactly these)."""
    from scipy.spatial.transform import Rotation

    if not len(a):
        return np.zeros((0, 6))
    w = Rotation.from_matrix(b[:, :3, :3] @ a[:, :3, :3].transpose(0, 2, 1)).as_rotvec() / dt
    return np.concatenate([(b[:, :3, 3] - a[:, :3, 3]) / dt, w], 1)


def _surface_travel(a: np.ndarray, b: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """[N] bound on how far a point within ``radius`` [N] of the origin moves from pose a
    [N, 4, 4] to pose b [m]: the origin's travel plus the turn's angle times the radius."""
    return np.linalg.norm(b[:, :3, 3] - a[:, :3, 3], axis=1) + turn_angle(a, b) * radius


class WorldStepper:
    """The control step of an :class:`~gausstac_maniskill.mpm.solver.MPMWorld` (a part of it: the
    state it advances is the world's)."""

    @property
    def bit_reproducible(self) -> bool:
        """Whether a step from a given state always gives the same bits (the CPU's slab
        scatter); the atomic scatter on CUDA sums in a run-dependent order."""
        return not self._atomic

    def wave_speed(self) -> float:
        """Largest explicit wave speed [m/s] of the awake groups (quasi-static ones with their
        pseudo-mass): the P-wave √((λ+2μ)/ρ), or √(2μ/ρ) where the volume term λ ln J is
        solved implicitly on cells (``SolverSettings.pressure``)."""
        speeds = [(math.sqrt(2.0 * g.material.mu / g.material.density)
                   if cell_pressure(g.material, self.settings.pressure) else g.material.wave_speed)
                  / math.sqrt(g.mass_scale * self._hold_factor(g))
                  for g in self.groups if g.awake and g.count > g.n_kinematic]
        return max(speeds, default=0.0)

    def plan_substeps(self, dt: float, driver_speed: float | None = None) -> tuple[int, float]:
        """Substeps for a control step of ``dt`` seconds from the CFL bound.

        Raises:
            SimulationError: the bound needs more than ``settings.max_substeps``.
        """
        self._push()
        if self._n_active == 0:
            return 1, dt  # nothing awake: nothing to resolve, whatever moves around
        s = self.settings
        c = self.wave_speed()
        v = self._vmax + (self._driver_speed(dt) if driver_speed is None else driver_speed)
        dt_max = s.cfl * s.dx / max(c + v, 1e-12)
        n = max(1, math.ceil(dt / dt_max - 1e-9))
        if n > s.max_substeps:
            raise SimulationError(
                f"control step dt={dt:g} s needs {n} substeps (CFL: Δt ≤ {s.cfl}·dx/(c+|v|) = "
                f"{dt_max:.3g} s with dx={s.dx:g} m, wave speed c={c:.3g} m/s, |v|max={v:.3g} m/s) but "
                f"SolverSettings.max_substeps={s.max_substeps}. Use a shorter control step, a coarser dx, "
                f"a softer material, quasi-static SolverSettings.mass_scaling > 1, or raise max_substeps.")
        return n, dt / n

    def _driver_speed(self, dt: float, travel=None) -> float:
        """Upper bound of link/collider surface speeds [m/s] over the next step of dt seconds
        (from :meth:`_boundary_travel`, or ``travel`` it returned)."""
        links, cols = self._boundary_travel() if travel is None else travel
        return float(max(links.max(initial=0.0), cols.max(initial=0.0))) / dt

    def _boundary_travel(self) -> tuple[np.ndarray, np.ndarray]:
        """Upper bounds [m] of how far each link's [L] and each collider's [C] surface moves over
        the next step: the origin's travel plus the turn's angle times the body's radius."""
        links = _surface_travel(self._link_prev, self._link_next, self._link_radius)
        cols = np.zeros(0)
        if self.colliders:
            nxt = self._collider_poses()
            r = np.array([_collider_radius(c) for c in self.colliders])
            far = ~np.isfinite(r)
            if far.any():  # no bound: the farthest particle from the collider's end origin
                self._pull(("x",))
                x = self._host_parts.x if self.num_particles else np.zeros((1, 3))
                r[far] = [float(np.linalg.norm(x - T[:3, 3], axis=1).max()) for T in nxt[far]]
            cols = _surface_travel(self._col_prev, nxt, r)
        return links, cols

    def step(self, dt: float, min_substeps: int = 1) -> StepInfo:
        """Advance one control step of ``dt`` seconds; links and colliders move from
        their previous pose to the last one set. Returns a :class:`StepInfo`.

        ``min_substeps``: take at least this many substeps (more than the CFL bound asks):
        a single scene then steps exactly as it would inside a batch whose other envs
        needed that many (the batched co-simulator's equivalence test).

        Raises:
            ConfigError: dt is not a positive finite number.
            SimulationError: the CFL bound cannot be met, a value became NaN/inf,
                or the active region grew beyond ``settings.max_grid_cells``.
        """
        if not (isinstance(dt, (int, float, np.floating)) and math.isfinite(dt) and dt > 0):
            raise ConfigError(f"step(dt={dt!r}): dt must be a positive finite number of seconds")
        t0 = time.perf_counter()
        self._push()
        travel = self._boundary_travel()
        driver = self._driver_speed(float(dt), travel)
        if self.settings.hold_scaling > 1.0:
            self._choose_hold(float(dt), travel)
        n_sub, dt_sub = self.plan_substeps(float(dt), driver)
        if int(min_substeps) > n_sub and self._n_active:
            n_sub, dt_sub = int(min_substeps), float(dt) / int(min_substeps)
        # particles farther than this from a collider cannot reach it within a substep
        self._reach = 2.0 * (self._vmax + driver) * dt_sub
        self._upload_consts()
        self._upload_poses()
        frozen = self._choose_patch() if self._patch is not None else None
        d = self._dev
        twists = _twists(self._link_prev, self._link_next, float(dt))
        if self._n_active:
            # groups that touched a collider in the last step keep their velocity (follow_links)
            change = np.zeros((max(len(twists), 1), 9), np.float32)
            change[:len(twists)] = np.concatenate([twists - self._link_twist, self._link_prev[:, :3, 3]], 1)
            if np.any(change[:, :6]) and any(g.awake and g.quasi_static for g in self.groups):
                d.twist_change.from_numpy(change)
                d.group_touched.fill(0)
                groups_in_contact(self._pack["P"], d.active, self._n_active, True, d.group_touched)
                K.follow_links(self._pack["P"], d.active, self._n_active, d.group_qs, d.group_touched,
                               d.twist_change)
            K.reset_contact(self._pack["P"], d.active, self._n_active)
        d.col_impulse.fill(0.0)
        d.pair_impulse.fill(0.0)
        self._stale = set(_STATE_FIELDS)  # from here on the device holds the newer state
        cells = 0
        flags = self._advance_flags()
        for k in range(n_sub):
            if self._n_active == 0:
                break
            cells = self._substep(k / n_sub, (k + 1) / n_sub, dt_sub, flags)
        self._check_health()
        if self._cellp and self._n_active and int(d.cell_count.to_numpy()[1]):
            raise SimulationError(
                f"the cell pressure ran out of cell slots at step {self.step_count + 1} ({d.slot_cell.shape[0]} "
                f"for {self.num_particles} particles): the material spread to more than one cell per two particles. "
                f"Use SolverSettings(pressure='explicit') for such strongly expanding bodies.")
        if self._n_active and n_sub:
            # kinematic particles onto the link's end pose (the substeps place them at each
            # substep's start); with F-bar the stress is then brought up to the final F
            self._prepare(1.0, 1.0 + 1e-6, dt_sub)
            if self._fbar or self._cellp:
                K.fbar_update(self._world_pack(), self._nh_only(), self._two_fields, self._atomic, self._fbar,
                              self._cellp)
        if frozen is not None and len(frozen):
            carry_rigidly(self._pack["P"], d.patch_frozen, len(frozen), float(dt), d.link_pose)
        if self._patched and self._n_active:
            self._note_patch_contact()
        if self._n_active and self.contact == "particle":
            K.reduce_contact(self._pack["P"], self._dev_parts.X0, d.active, self._pack["R"], self.num_envs,
                             self._pair_impulse.shape[1])
        self._col_impulse = d.col_impulse.to_numpy().astype(np.float64)[: len(self.colliders)]
        n_slot = self._pair_impulse.shape[1]
        pairs = d.pair_impulse.to_numpy().astype(np.float64)
        self._pair_impulse = pairs[: len(self.link_names) * n_slot].reshape(len(self.link_names), n_slot, 7)
        torn = self._torn_groups() if self._n_active else []
        if self.settings.hold_scaling > 1.0 and self._n_active and any(g.quasi_static for g in self.groups):
            d.group_drift.fill(0.0)
            K.group_drift(self._pack["P"], d.active, self._n_active, d.link_pose, float(dt), d.group_drift)
            drift = d.group_drift.to_numpy()
            for i, g in enumerate(self.groups):
                g.drift = float(drift[i]) if g.awake else math.inf
        self._link_prev = self._link_next.copy()
        self._link_twist = twists
        self._col_prev = self._collider_poses()
        self._last_dt_ctrl = float(dt)
        self.time += float(dt)
        self.step_count += 1
        self._rest_torn(torn, driver)
        self.last_step = StepInfo(n_sub, dt_sub, time.perf_counter() - t0, self._n_active, cells)
        return self.last_step

    def _choose_hold(self, dt: float, travel: tuple[np.ndarray, np.ndarray]) -> None:
        """Which awake quasi-static groups hold (see the module docstring): those whose link and
        env colliders move their surfaces slower than ``hold_speed / 5`` over the step (``travel``:
        :meth:`_boundary_travel`), with no soft body awake in their env, and that either hold
        already or drifted slower than ``hold_speed`` relative to their link at the end of the
        last step."""
        s = self.settings
        limit = 0.2 * s.hold_speed * dt  # boundary travel [m] that counts as standing still
        links, cols = travel
        for g in self.groups:
            if not (g.awake and g.quasi_static and g.link >= 0):
                continue
            still = links[g.link] <= limit and all(cols[k] <= limit for k in range(len(cols))
                                                   if self.model.colliders[k].env == g.env)
            still = still and not any(h.awake and not h.quasi_static and h.env == g.env for h in self.groups)
            self._set_hold(g, still and (g.hold or g.drift < s.hold_speed))

    def _hold_factor(self, g: Group) -> float:
        """What group g's pseudo-mass is multiplied by now: ``hold_scaling`` while it holds, else 1.
        Its relaxation rate is divided by the square root (the same damping ratio)."""
        return self.settings.hold_scaling if g.hold else 1.0

    def _set_hold(self, g: Group, hold: bool) -> None:
        """Put group g on its hold pseudo-mass or back. Its particles' mass is set anew from
        density, pseudo-mass and rest volume, as add_group set it, so switching back and forth
        never drifts; its ``mass_scale`` and ``relaxation`` stay as add_group set them."""
        if hold == g.hold:
            return
        g.hold = hold
        mass = np.float32(g.material.density * g.mass_scale * self._hold_factor(g)
                          * float(self._host_parts.vol[g.start]))
        if self._on_device():
            K.fill_mass(self._pack["P"], g.start, g.stop, float(mass))
        self._host_parts.mass[g.start:g.stop] = mass

    def _torn_groups(self) -> list[tuple[Group, int]]:
        """Awake quasi-static groups with particles beyond their ``tear`` distance from their
        rest places after this step, and how many (:func:`kernels.torn_particles`)."""
        if not any(g.awake and g.tear > 0.0 for g in self.groups):
            return []
        d = self._dev
        d.torn.fill(0)
        K.torn_particles(self._pack["P"], d.X_rest if self._patch is not None else self._dev_parts.X0, d.active,
                         self._n_active, d.link_pose, d.group_tear, d.torn)
        counts = d.torn.to_numpy()
        return [(g, int(counts[i])) for i, g in enumerate(self.groups) if g.awake and counts[i] > 0]

    def _rest_torn(self, torn: list[tuple[Group, int]], driver: float) -> None:
        """Put torn groups back on their rest shape, and say so. An object pushed into a pad's
        core by the pose source (a link driven through it faster than the rigid solver holds it
        out) leaves the layer no elastic state: contact pushes it out while its core is inside,
        and the part pushed beyond the grid stencil of its core stays detached, reading a
        depth the pad cannot have (e.g. a fast strike on a grasped cube). An object that drags
        a stuck layer farther than it stretches does the same."""
        for g, count in torn:
            warnings.warn(SimulationWarning(
                f"group {g.name!r}: {count} of its {g.count - g.n_kinematic} soft particles were torn more than "
                f"{g.tear * 1e3:.3g} mm from their rest places on link {self.link_names[g.link]!r} at step "
                f"{self.step_count} (t={self.time:.4g} s; link surfaces moved up to {driver:.3g} m/s), farther than "
                f"any elastic state of its layer reaches: an object was driven into its core, or dragged the "
                f"layer off it. The group was put back on its rest shape; its contact and maps of this step "
                f"are not physical."), stacklevel=3)
            self.rest_group(g.name)

    def _prepare(self, a0: float, a1: float, dt: float) -> int:
        """Frames, kinematic particles and the slab sort for the substep [a0, a1] of the
        control step; returns the active box's number of cells (see :func:`kernels.prepare`)."""
        s = self.settings
        ncell = int(K.prepare(self._pack["placement"], a0, a1, dt, self._atomic))
        if ncell > s.max_grid_cells or ncell < 0:
            ox, oy, oz, nx, ny, nz = (int(b) for b in self._dev.box.to_numpy()[:6])
            raise SimulationError(self._explode_message(np.array([ox, oy, oz]) + s.grid_margin,
                                                        np.array([ox + nx, oy + ny, oz + nz]) - s.grid_margin - 3))
        need = ncell * (2 if self._two_fields else 1) * self.num_envs
        if need > self._grid_cap:
            self._alloc_grid(int(min(need * 1.5, 2 * s.max_grid_cells)))
        return ncell

    def _world_pack(self):
        """The kernels' argument pack (kernels.World) over the current device arrays."""
        pk = self._pack
        if pk.get("W") is None:
            pk["W"] = K.World(P=pk["P"], G=pk["G"], S=pk["S"], O=pk["O"])
        return pk["W"]

    def _choose_patch(self) -> np.ndarray | None:
        """The active patch of this step (:mod:`~gausstac_maniskill.mpm.patch`): rewrites the
        awake lists, the kinematic flags and the shell's rest coordinates on the device.
        Returns the indices of the frozen particles (carried rigidly after the substeps),
        or None when every awake particle is simulated."""
        hp, dp, d, n = self._host_parts, self._dev_parts, self._dev, max(self.num_particles, 1)
        self._patched = []
        if not any(g.awake for g in self.groups):
            return None
        kind = hp.kind
        gids = [i for i, g in enumerate(self.groups) if g.awake and g.quasi_static and g.link >= 0
                and g.count > g.n_kinematic and g.patch_state != 2]
        gaps = {}
        if gids and self.colliders and not self._two_fields:
            cand = np.concatenate([np.arange(self.groups[i].start, self.groups[i].stop, dtype=np.int32)
                                   for i in gids])
            d.patch_cand.from_numpy(np.resize(cand, n))
            rest_gap(self._pack["P"], self._pack["S"], d.X_rest, d.link_pose, d.col_pose,
                     d.patch_cand, len(cand), d.patch_gap)
            gap = d.patch_gap.to_numpy()
            start = 0
            for i in gids:
                gaps[i] = gap[start:start + self.groups[i].count]
                start += self.groups[i].count
        parts, bind, frozen = [], [], []
        for i, g in enumerate(self.groups):
            if not g.awake:
                continue
            idx = np.arange(g.start, g.stop, dtype=np.int32)
            sl = slice(g.start, g.stop)
            split = self._patch.split(i, hp.X0[sl], kind[sl] == 0, gaps[i]) if i in gaps else None
            if split is not None and not split[0].any() and g.patch_state == 1:
                g.patch_state, split = 2, None  # its contact has just ended: relax it whole
            if split is None:
                parts.append((g.env, idx))
                continue
            patch, shell = split  # nothing touches a group at rest: all of it rides with the link
            self._patched.append(i)
            parts.append((g.env, idx[patch | shell]))
            bind.append(idx[shell & (kind[sl] == 0)])
            frozen.append(idx[~(patch | shell)])
        active, env_rows = self._env_major(parts)
        d.env_rows.from_numpy(env_rows)
        kd = kind.copy()
        bind = np.concatenate(bind) if bind else np.zeros(0, np.int32)
        kd[bind] = 1
        active_kin = active[kd[active] == 1]
        dp.kind.from_numpy(np.resize(kd, n))
        d.active.from_numpy(np.resize(active, n))
        d.active_kin.from_numpy(np.resize(active_kin, n))
        self._n_active, self._n_kin = len(active), len(active_kin)
        self._upload_counts()
        if len(bind):
            d.patch_bind.from_numpy(np.resize(bind, n))
            bind_in_place(self._pack["P"], dp.X0, d.patch_bind, len(bind), d.link_pose)
        if not frozen:
            return None
        frozen = np.concatenate(frozen)
        d.patch_frozen.from_numpy(np.resize(frozen, n))
        return frozen

    def _note_patch_contact(self) -> None:
        """After a patched step: a patched group in contact holds frozen deformation (state 1);
        once its contact ends it is simulated whole until put back at rest (state 2)."""
        d = self._dev
        d.patch_contact.from_numpy(np.zeros(max(len(self.groups), 1), np.int32))
        groups_in_contact(self._pack["P"], d.active, self._n_active, False, d.patch_contact)
        touched = d.patch_contact.to_numpy()
        for i in self._patched:
            g = self.groups[i]
            if touched[i]:
                g.patch_state = 1
            elif g.patch_state == 1:
                g.patch_state = 2

    def _nh_only(self) -> bool:
        return all(m.model == "neo_hookean" for m in self.materials)

    def _stress_flags(self) -> tuple[bool, int]:
        """(F-bar for some material, CG iterations of the cells' volume term or 0): the kernels'
        compile-time switches for this world's materials."""
        s = self.settings
        cells = [cell_pressure(m, s.pressure) for m in self.materials]
        return bool(s.fbar) and not all(cells), (int(s.pressure_iterations) if any(cells) else 0)

    def _advance_flags(self) -> tuple:
        """:func:`kernels.advance`'s compile-time switches for this world, in its order after dt."""
        mode = 0 if not self.colliders else (1 if self.contact == "particle" else 2)
        return self._fbar, mode, self._nh_only(), self._two_fields, self._atomic, self._cellp

    def _substep(self, a0: float, a1: float, dt: float, flags: tuple) -> int:
        """One substep [a0, a1] of the control step, ``dt`` seconds long (``flags``:
        :meth:`_advance_flags`); returns its active box's number of cells."""
        ncell = self._prepare(a0, a1, dt)
        K.advance(self._world_pack(), dt, *flags)
        return ncell

    def _explode_message(self, lo, hi) -> str:
        x = self._dev_parts.x.to_numpy()
        parts = []
        for g in self.groups:
            if g.awake:
                gx = x[g.start:g.stop]
                parts.append(f"{g.name!r}: [{gx.min(0).round(4).tolist()} .. {gx.max(0).round(4).tolist()}] m")
        ext = (hi - lo + 1) * self.settings.dx
        return (f"the active particles spread over {ext.round(4).tolist()} m "
                f"(> SolverSettings.max_grid_cells={self.settings.max_grid_cells} cells of dx="
                f"{self.settings.dx:g} m) at t={self.time:.4g} s, step {self.step_count}: particles are "
                f"flying apart (unstable simulation?). Group extents: " + "; ".join(parts))

    def _check_health(self) -> None:
        if not self._n_active:
            self._vmax = 0.0
            return
        d = self._dev
        K.chunk_health(self._pack["P"], d.active, self._n_active, K.NCHUNK, d.first_bad, d.vmax_chunk)
        bad = d.first_bad.to_numpy()
        self._vmax = float(d.vmax_chunk.to_numpy().max())
        bad = bad[bad >= 0]
        if len(bad):
            p = int(bad.min())
            g = next(g for g in self.groups if g.start <= p < g.stop)
            raise SimulationError(
                f"particle {p - g.start} of group {g.name!r} has a NaN/inf position, velocity or "
                f"deformation gradient after step {self.step_count + 1} (t={self.time:.4g} s, "
                f"{self.last_step.substeps if self.last_step else '?'} substeps of the previous step). "
                f"The simulation is unstable: lower SolverSettings.cfl, check material parameters "
                f"(E={g.material.E:g} Pa, nu={g.material.nu:g}) and link/collider motions.")
