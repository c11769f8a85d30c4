"""``python -m gausstac_maniskill.bench soft [--dx 1e-3 ...] [--pad-solvers mpm fem] [--no-blocks]
[--reference SIZE ...]``
— a pad and a soft object as two bodies (two velocity fields).

* sponge: a foam sponge (12 × 12 × 6 mm, 50 kPa) pressed 1.3 mm into the index pad
  (:func:`sponge_scene`), with the sponge in its own field and in the pads', and against the pad
  solved at equilibrium: three readings of the same force (the force map, the pad's stress, the
  sponge's stress), the closest approach of the two bodies' particles and the time per step.
  ``--reference``: the held force with the pad rigid, solved at equilibrium (:func:`rigid_pad_reference`).
* blocks: two free 10 × 8 × 8 mm blocks closing at 0.1 and 1 m/s (:func:`collide`): closest
  approach, coefficient of restitution and momentum change.
"""
from __future__ import annotations

import os
import time

import numpy as np

from .common import arch_option, cli, write_report

INDEX = "link_3.0_tip"
SPONGE = dict(E=5e4, nu=0.3, density=60.0)  # Pa, -, kg/m³
SPONGE_SIZE = (12e-3, 12e-3, 6e-3)  # m
BOND = 5e-3  # m: the sponge is bound to its holder beyond this height above its face
CLEARANCE = 0.3e-3  # m: face to pad apex at the start
PRESS = 1.3e-3  # m
BLOCK = dict(E=1e5, nu=0.3, density=1000.0)  # the free blocks: Pa, -, kg/m³


def sponge_scene(field: int = 1, dx: float = 1e-3, pad_solver: str = "mpm", **sim_kwargs):
    """The index pad (link pose: 10 cm up) and the bound sponge below its sensor axis.

    Returns ``(sim, press, reading)``: ``press(depth)`` steps 50 ms with the holder moved
    ``depth`` [m] towards the pad (negative: away) and returns the tactile maps;
    ``reading()`` returns ``(map_force, pad_stress_force, sponge_stress_force)`` [N], the
    normal force in three readings (pressing positive)."""
    from ..config import Material
    from ..config import SolverSettings
    from ..cosim import GaussTacSim
    from ..geometry import box_particles
    from ..tactile import allegro_pad_specs
    from ..transforms import make_pose

    pose = np.eye(4)
    pose[2, 3] = 0.1
    spec = next(s for s in allegro_pad_specs() if s.link == INDEX)
    sim = GaussTacSim([spec], {INDEX: pose}, settings=SolverSettings(dx=dx), pad_solver=pad_solver,
                      **sim_kwargs)
    W = pose @ sim.pads[INDEX].sensor_frame  # sensor z: out of the pad, towards the sponge
    R = W[:3, :3]
    sx, sy, sz = SPONGE_SIZE
    local = box_particles(np.array([-sx / 2, -sy / 2, 0.0]), np.array([sx / 2, sy / 2, sz]),
                          sim.settings.particle_spacing)
    base = W[:3, 3] + R[:, 2] * CLEARANCE
    sim.world.add_link("holder", make_pose(base, R))
    kin = local[:, 2] > BOND
    sim.add_soft_object("sponge", local @ R.T + base, Material(**SPONGE), link="holder", kinematic=kin,
                        field=field)
    grad = np.where(kin[:, None], 0.0, -R[:, 2] / BOND)  # ∇φ of φ = 1 - z/BOND (sponge frame z)
    last = {}

    def press(depth: float):
        last["maps"] = sim.step({INDEX: pose, "holder": make_pose(base - R[:, 2] * depth, R)}, 0.05)
        return last["maps"]

    def reading():
        in_map = float(last["maps"][INDEX]["force"].sum())
        on_pad = -float(sim.pad_stress_force(INDEX)[2])  # sensor z is negative when pushed in
        on_sponge = float(sim.world.virtual_work_force("sponge", grad) @ R[:, 2])
        return in_map, on_pad, on_sponge

    return sim, press, reading


def rigid_pad_reference(size: float, friction: float = 0.5) -> float:
    """The sponge scene's held force [N] with the pad rigid (its link mesh as the indenter) and
    the sponge a linear elastic body of cube elements of edge ``size`` [m] (:mod:`..fem`; the
    bond at BOND, Coulomb ``friction``, the contact read at the deformed surface): an
    independent solver's value of what the sponge pushes with when the pad does not yield.
    The pads that do yield read below it, by their share of the compression."""
    from ..fem.contact import QuasiStaticBody
    from ..fem.indenters import Indenters
    from ..fem.hex import voxel_body
    from ..fem.pad import collider_indenter
    from ..geometry import MeshCollider
    from ..tactile import allegro_pad_specs, build_pad, pad_mesh
    from ..transforms import make_pose
    from ..urdf import default_hand_urdf

    spec = next(s for s in allegro_pad_specs() if s.link == INDEX)
    mesh = pad_mesh(spec, default_hand_urdf())
    pose = np.eye(4)
    pose[2, 3] = 0.1
    W = pose @ build_pad(spec, mesh, 5e-4, 1e-3).sensor_frame  # the scene's sensor frame (any spacing)
    n = np.round(np.array(SPONGE_SIZE) / size).astype(int)
    ijk = np.stack(np.meshgrid(*[np.arange(k) for k in n], indexing="ij"), -1).reshape(-1, 3)
    origin = np.array([-SPONGE_SIZE[0] / 2, -SPONGE_SIZE[1] / 2, 0.0])
    body = voxel_body(ijk, origin, size)
    face = np.flatnonzero(ijk[:, 2] == 0)
    bonded = (origin + body.nodes * size)[:, 2] >= BOND - 1e-9  # the far 1 mm, held by the holder
    sponge = QuasiStaticBody(body, SPONGE["E"], SPONGE["nu"], bonded,
                             origin + (ijk[face] + [0.5, 0.5, 0.0]) * size, face, name="sponge")
    collider = MeshCollider(pose=pose, mesh=mesh, sdf_dx=2.5e-4, friction=friction)  # SDF within ~1 µm here
    res = None
    for depth in (0.5e-3, 1e-3, PRESS):  # the press in steps, each warming the next (friction holds)
        frame = make_pose(W[:3, 3] + W[:3, 2] * (CLEARANCE - depth), W[:3, :3])
        res = sponge.solve(Indenters(collider_indenter(collider, frame)), geometry="deformed", warm=res,
                           max_iterations=200)
    return float(res.total_force[2])


def closest_approach(a: np.ndarray, b: np.ndarray) -> float:
    """Smallest distance [m] between a point of ``a`` [N, 3] and one of ``b`` [M, 3]."""
    from scipy.spatial import cKDTree

    return float(cKDTree(a).query(b)[0].min())


def run_sponge(field: int, steps: int = 6, dx: float = 1e-3, pad_solver: str = "mpm") -> dict:
    """Press the sponge (3 ramp steps, then held); readings of the last step, and the wall
    time per held step (the MPM's and, for ``pad_solver="fem"``, the pad's solve with it)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the pad's layer spans fewer than 4 cells at dx > 1 mm
        sim, press, reading = sponge_scene(field, dx, pad_solver, fem_precompute=pad_solver == "fem" or None)
    walls, closest = [], np.inf
    for k in range(steps):
        t0 = time.perf_counter()
        press(PRESS * min(1.0, (k + 1) / 3))
        walls.append(time.perf_counter() - t0)
        closest = min(closest, closest_approach(sim.pad_particles(INDEX)[0], sim.world.positions("sponge")))
    in_map, on_pad, on_sponge = reading()
    return dict(field=field, map=in_map, pad_stress=on_pad, sponge_stress=on_sponge, dx=dx, pad_solver=pad_solver,
                closest=closest / sim.settings.particle_spacing, step_ms=1e3 * float(np.mean(walls[3:])),
                substeps=sim.world.last_step.substeps)


def collide(field_b: int, speed: float = 0.1, steps: int = 12, dx: float = 1e-3) -> dict:
    """Two free blocks closing at ``speed`` [m/s] (block b in field ``field_b``), ``steps``
    steps of 1 ms. Returns the mean x velocities [m/s] after, the total momentum before and
    after [kg m/s], one block's momentum [kg m/s], the closest approach [m] and the particle
    spacing [m]."""
    from ..config import Material, SolverSettings
    from ..geometry import box_particles
    from ..mpm import MPMWorld

    s = SolverSettings(dx=dx, gravity=(0.0, 0.0, 0.0), mass_scaling=1.0, max_substeps=2000)
    w = MPMWorld(s)
    m = Material(**BLOCK)
    a = box_particles([-0.0105, -0.004, -0.004], [-0.0005, 0.004, 0.004], s.particle_spacing)
    w.add_group("a", a, m, velocity=[speed / 2, 0, 0])
    w.add_group("b", a + [0.011, 0.0, 0.0], m, velocity=[-speed / 2, 0, 0], field=field_b)
    mass = m.density * s.particle_spacing ** 3

    def momentum():
        return mass * (w.velocities("a").sum(0) + w.velocities("b").sum(0))

    p0, closest = momentum(), np.inf
    for _ in range(steps):
        w.step(1e-3)
        closest = min(closest, closest_approach(w.positions("a"), w.positions("b")))
    return dict(va=float(w.velocities("a").mean(0)[0]), vb=float(w.velocities("b").mean(0)[0]), p0=p0,
                p1=momentum(), p_block=mass * len(a) * speed / 2, closest=closest, spacing=s.particle_spacing,
                speed=speed)


def format_tables(sponges: list[dict], blocks: list[dict]) -> str:
    name = {0: "one field (shared)", 1: "two fields (default)"}
    pad = {"mpm": "MPM", "fem": "at equilibrium (`fem`)"}
    out = ["Sponge pressed 1.3 mm into the index pad (default hand settings); held-step readings [N]",
           "", "| pad | sponge in | dx [mm] | map | pad stress | sponge stress | map / sponge | pad stress / sponge | "
           "closest approach [spacings] | ms / 50 ms held step |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in sponges:
        out.append(f"| {pad[r['pad_solver']]} | {name[r['field']]} | {r['dx'] * 1e3:g} | {r['map']:.3f} | "
                   f"{r['pad_stress']:.3f} | {r['sponge_stress']:.3f} | "
                   f"{r['map'] / r['sponge_stress'] - 1:+.1%} | {r['pad_stress'] / r['sponge_stress'] - 1:+.1%} | "
                   f"{r['closest']:.2f} | {r['step_ms']:.0f} |")
    if not blocks:
        return "\n".join(out)
    out += ["", "Two free blocks colliding (dx = 1 mm, 12 steps of 1 ms)", "",
            "| block b in | closing speed [m/s] | closest approach [spacings] | restitution | "
            "momentum change / block momentum |", "|---|---|---|---|---|"]
    for r in blocks:
        e = (r["vb"] - r["va"]) / r["speed"]
        dp = float(np.abs(r["p1"] - r["p0"]).max() / r["p_block"])
        out.append(f"| {name[r['field']]} | {r['speed']:g} | {r['closest'] / r['spacing']:.2f} | {e:.2f} | {dp:.1e} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = cli("soft", __doc__)
    arch_option(ap)
    ap.add_argument("--out", default="out/bench_soft", help="folder for soft.md")
    ap.add_argument("--dx", type=float, nargs="+", default=[1e-3], help="grid spacings [m] of the sponge scene")
    ap.add_argument("--pad-solvers", nargs="+", default=["mpm", "fem"], choices=["mpm", "fem"],
                    help="the pads the sponge meets (the MPM's also with the sponge in the pads' field, at 1 mm)")
    ap.add_argument("--no-blocks", action="store_true", help="skip the free blocks")
    ap.add_argument("--reference", type=float, nargs="*", default=[],
                    help="element sizes [m] of the rigid-pad reference (rigid_pad_reference), e.g. 1e-3 5e-4 3.3333e-4")
    args = ap.parse_args(argv)
    from tqdm import tqdm

    from .. import backend

    arch = backend.init(args.arch)
    t0 = time.perf_counter()
    jobs = [("sponge", 1, dx, solver) for solver in args.pad_solvers for dx in args.dx]
    if "mpm" in args.pad_solvers and 1e-3 in args.dx:
        jobs.append(("sponge", 0, 1e-3, "mpm"))
    if not args.no_blocks:
        jobs += [("blocks", f, v) for v in (0.1, 1.0) for f in (1, 0)]
    sponges, blocks = [], []
    for job in tqdm(jobs, desc="soft contact"):
        if job[0] == "sponge":
            sponges.append(run_sponge(job[1], dx=job[2], pad_solver=job[3]))
        else:
            blocks.append(dict(collide(job[1], job[2]), field=job[1]))
    text = (f"on {arch} ({os.cpu_count()} cores), total {time.perf_counter() - t0:.0f} s\n\n"
            + format_tables(sponges, blocks))
    if args.reference:
        rows = [f"| {size * 1e3:.3g} | {rigid_pad_reference(size):.4f} |" for size in args.reference]
        text += ("\n\nThe sponge against the pad made rigid, solved at equilibrium (linear elastic cube elements, "
                 "μ = 0.5)\n\n| element [mm] | held force [N] |\n|---|---|\n" + "\n".join(rows))
    print(text)
    write_report(args.out, "soft.md", text)
    return 0
