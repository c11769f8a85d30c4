"""``python -m gausstac_maniskill.bench hold`` — what PhysX does with the pads' forces on a held cube.

A diagnostic of the object springs (:mod:`gausstac_maniskill.tasks.contact_spring`). The
``GaussTac-GraspLiftCube-v1`` expert (``pd_joint_pos``, SAPIEN 100 Hz, ``pad_reaction=True``)
holds a light cube; after ``--steps`` control steps the MPM forces of each pad on the cube
are printed, then one SAPIEN step is taken under variants of the springs, each after the
same episode replayed from the reset (a saved and restored PhysX state did not give the
same step: ``set_sim_state`` does not restore all PhysX carries between steps). Each starts
from the env's own setting for the step (the springs, and the pads' reaction folded into the
finger drives), then:

* ``env``: nothing changed;
* ``no friction drives``: the drives across each force's line (friction's response) off;
  without gravity, the two limits alone should settle the cube where they balance, at
  (|F_index| - |F_thumb|) / (K_index + K_thumb) toward the thumb (the "two limits" line);
* ``friction caps x s``: the friction drives' force limits μ|F| scaled by s;
* ``twist drives off``: the springs' twist drives (about each force's line) off;
* ``<pad> limit alone, no gravity``: only that pad's one-sided limit (no friction, no twist,
  the other springs released), the cube weightless for the step (a falling cube opens one
  pad's gap and closes the other's). An implicit spring of stiffness K preloaded by a gap
  δ = |F|/K moves a free body of mass m by δ r / (1 + r), r = K dt² / m, in one step (the
  "implicit spring" column), which is what the limit should do (it does, off the hand:
  ``tests/tasks/test_contact_spring.py``);
* ``all released`` (with and without gravity): no spring, the references.

Each row: the cube's displacement [µm] along the pinch axis (thumb to index) and vertically.
"""
from __future__ import annotations

import numpy as np
import sapien

from . import cli, write_report


def _spring_variants(u, springs: dict):
    """name -> function that sets the springs for one SAPIEN step. Every one starts from the
    env's own setting (:meth:`_before_simulation_step`: the object springs and the pads'
    reaction folded into the finger drives; without the fold the fingertips move 50-70 µm in
    the step and carry the cube with them), then changes the springs."""
    cube = u.cube._objs[0].find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)

    def env_then(change=None, gravity=True):
        def fn():
            u._before_simulation_step()
            cube.disable_gravity = not gravity
            if change is not None:
                change()
        return fn

    def no_friction():
        for s in springs.values():
            if s.active:
                s.drive.set_drive_property_y(0.0, 0.0, 0.0, "force")
                s.drive.set_drive_property_z(0.0, 0.0, 0.0, "force")

    def no_twist():
        for s in springs.values():
            if s.active:
                s.drive.set_drive_property_twist(0.0, 0.0, 0.0, "force")

    def alone(keep):
        def fn():
            no_friction()
            no_twist()
            for name, s in springs.items():
                if name != keep:
                    s.release()
        return fn

    def caps(scale):
        def fn():
            for s in springs.values():
                if s.active:
                    for get, put in ((s.drive.get_drive_property_y, s.drive.set_drive_property_y),
                                     (s.drive.get_drive_property_z, s.drive.set_drive_property_z)):
                        k, d, cap, mode = get()
                        put(k, d, cap * scale, mode)
        return fn

    def released():
        for s in springs.values():
            s.release()

    out = {"env": env_then(), "no friction drives": env_then(no_friction),
           "no friction drives, no gravity": env_then(no_friction, gravity=False)}
    out.update({f"friction caps x {s:g}": env_then(caps(s)) for s in (0.01, 1e-4)})
    out["friction caps x 0.001, no gravity"] = env_then(caps(1e-3), gravity=False)
    out["twist drives off, no gravity"] = env_then(no_twist, gravity=False)
    out.update({f"{pad} limit alone, no gravity": env_then(alone(pad), gravity=False) for pad in springs})
    out["all released, no gravity"] = env_then(released, gravity=False)
    out["all released"] = env_then(released)
    return out


#: the pads of the pinch and their links (Allegro)
PADS = {"thumb": "link_15.0_tip", "index": "link_3.0_tip"}


def _springs(u) -> dict:
    """pad -> the ContactSpring between its link and the cube (env 0)."""
    return {p: u._object_springs[0][u.pad_links.index(link)][0] for p, link in PADS.items()}


def _pinch_axis(u) -> np.ndarray:
    """Unit vector from the thumb tip link to the index tip link (world frame)."""
    links = u.agent.robot.links_map
    axis = np.asarray(links[PADS["index"]].pose.p[0] - links[PADS["thumb"]].pose.p[0], np.float64)
    return axis / np.linalg.norm(axis)


def _pad_rows(u, axis: np.ndarray, mass: float) -> tuple[list[str], dict]:
    """The MPM force of each pad on the cube and its spring's constants (table lines), and the
    motion [µm] an implicit spring would give in the rows where it is predictable."""
    dt, springs = u.sim_timestep, _springs(u)
    lines = ["| pad | MPM force on the cube [N] | along the pinch axis [N] | indentation [mm] | K [N/m] "
             "| δ = abs(F)/K [µm] | r = K dt²/m | implicit spring alone: δ r/(1+r) [µm] |", "|---|---|---|---|---|---|---|---|"]
    net, stiffness, expected = np.zeros(3), 0.0, {}
    for p, link in PADS.items():
        row = u.cosims[0].link_contacts(link).get("cube", np.zeros(7))
        f = -row[:3]
        net += f
        k = springs[p].drive.get_limit_x()[2] if springs[p].active else 0.0
        stiffness += k
        delta = float(np.linalg.norm(f)) / k if k else 0.0
        r = k * dt ** 2 / mass
        alone = delta * r / (1 + r) * 1e6
        expected[f"{p} limit alone, no gravity"] = f"{alone:.1f} along the pad's force"
        lines.append(f"| {p} | {np.round(f, 3).tolist()} | {f @ axis:+.3f} | {row[6] * 1e3:.2f} | {k:.0f} "
                     f"| {delta * 1e6:.1f} | {r:.0f} | {alone:.1f} |")
    lines.append(f"| net | {np.round(net, 3).tolist()} | {net @ axis:+.3f} | | | | | |")
    balance = (net @ axis) / max(stiffness, 1e-12) * 1e6
    lines.append(f"\nTwo limits alone balance the cube at {balance:+.1f} µm along the axis.")
    expected["no friction drives, no gravity"] = f"{balance:+.1f} along the axis (two limits)"
    expected["all released"] = f"{-9.81 * dt ** 2 * 1e6:.0f} vertical (free fall)"
    return lines, expected


def main(argv: list[str] | None = None) -> int:
    ap = cli("hold", __doc__)
    ap.add_argument("--mass", type=float, default=0.01, help="cube mass [kg]")
    ap.add_argument("--dx", type=float, default=2e-3, help="MPM grid spacing [m]")
    ap.add_argument("--steps", type=int, default=60, help="expert control steps before the probe")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="out/bench_hold", help="folder for the report")
    args = ap.parse_args(argv)
    import gymnasium as gym
    from tqdm import tqdm

    import gausstac_maniskill.tasks  # noqa: F401  (registers the tasks with ManiSkill)

    from ..experts import make_expert

    env = gym.make("GaussTac-GraspLiftCube-v1", sim_backend="physx_cpu", obs_mode="state",
                   control_mode="pd_joint_pos", mpm_dx=args.dx, cube_mass=args.mass)

    def replay():
        obs, _ = env.reset(seed=args.seed)
        expert = make_expert(env)
        expert.reset()
        for _ in tqdm(range(args.steps), desc="hold", leave=False):
            obs, _, _, _, info = env.step(expert.act(obs))
        return expert, info

    try:
        u = env.unwrapped
        expert, info = replay()
        lines = [f"GraspLiftCube, {args.mass * 1e3:g} g cube, dx {args.dx * 1e3:g} mm, after {args.steps} expert steps "
                 f"(phase {expert.phase[0]}, cube speed {float(info['cube_speed'][0]) * 1e3:.3f} mm/s), "
                 f"SAPIEN dt {u.sim_timestep:g} s", ""]
        axis = _pinch_axis(u)
        pad_lines, expected = _pad_rows(u, axis, args.mass)
        lines += pad_lines
        lines += ["", "One SAPIEN step after the same episode:", "",
                  "| springs | cube along the pinch axis [µm] | cube vertical [µm] | thumb tip along the axis [µm] "
                  "| index tip along the axis [µm] | expected [µm] |", "|---|---|---|---|---|---|"]
        names = list(_spring_variants(u, _springs(u)))  # the row names (each row rebuilds its springs)
        for name in names:
            replay()
            springs = _springs(u)
            cube = u.cube._objs[0]
            tips = [springs[p].link for p in ("thumb", "index")]
            p0 = np.asarray(cube.pose.p, np.float64).copy()
            t0 = [np.asarray(t.pose.p, np.float64).copy() for t in tips]
            _spring_variants(u, springs)[name]()
            u.scene.step()
            dp = (np.asarray(cube.pose.p, np.float64) - p0) * 1e6
            cube.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent).disable_gravity = False  # for the next replay
            moved = [(np.asarray(t.pose.p, np.float64) - q0) @ axis * 1e6 for t, q0 in zip(tips, t0)]
            lines.append(f"| {name} | {dp @ axis:+.2f} | {dp[2]:+.2f} | {moved[0]:+.2f} | {moved[1]:+.2f} "
                         f"| {expected.get(name, '')} |")
    finally:
        env.close()
    text = "\n".join(lines)
    print(text)
    write_report(args.out, "hold.md", text)
    return 0
