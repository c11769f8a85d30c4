"""The GaussTac twins of ManiSkill's stock dexterous hands (``agents/dclaw.py``, ``trifinger.py``,
``allegro_touch.py``): registered; their pads build at the default resolution
(``SolverSettings()``: dx = 1 mm, 0.5 mm spacing) on the side their axis points to, within
their taxel grids; the URDF SAPIEN loads has the pad links' rigid cores below the pads (and
the D'Claw's plates and brackets) and loads in SAPIEN; the FSR Allegro keeps its 16 FSR links,
the 4 tip FSRs under the pads. A twin whose ManiSkill asset is absent skips with the reason."""
import math
import warnings

import numpy as np
import pytest
import trimesh

import gausstac_maniskill  # noqa: F401  (registers agents and tasks)
from gausstac_maniskill.agents import GaussTacAgent
from gausstac_maniskill.agents import allegro_touch, dclaw, trifinger
from gausstac_maniskill.agents.base import core_urdf
from gausstac_maniskill.config import SolverSettings
from gausstac_maniskill.errors import ResolutionWarning
from gausstac_maniskill.tactile import pad_geometry, pad_mesh
from gausstac_maniskill.tactile.pad import CORE_DEPTH
from gausstac_maniskill.urdf import link_mesh, link_names, parse_urdf, primitive_mesh

#: uid -> (module, class attribute, "missing" attribute, stock uid, pad name -> link)
TWINS = {
    "dclaw_gausstac": (dclaw, "DClawGaussTac", "DCLAW_MISSING", "dclaw",
                       {"f1": "link_f1_3", "f2": "link_f2_3", "f3": "link_f3_3"}),
    "trifingerpro_gausstac": (trifinger, "TriFingerProGaussTac", "TRIFINGER_MISSING", "trifingerpro",
                              {"f0": "finger_tip_link_0", "f120": "finger_tip_link_120",
                               "f240": "finger_tip_link_240"}),
    "allegro_hand_right_touch_gausstac": (allegro_touch, "AllegroHandRightTouchGaussTac", "TOUCH_MISSING",
                                          "allegro_hand_right_touch",
                                          {"thumb": "link_15.0_tip", "index": "link_3.0_tip", "middle": "link_7.0_tip",
                                           "ring": "link_11.0_tip"}),
}
SETTINGS = SolverSettings()
SPACING, DX = SETTINGS.dx / SETTINGS.particles_per_axis, SETTINGS.dx


def twin(uid):
    module, attr, missing, *_ = TWINS[uid]
    if getattr(module, missing):
        pytest.skip(getattr(module, missing))
    return getattr(module, attr)


def loaded_urdf(cls) -> str:
    """The URDF SAPIEN loads for ``cls`` (what ``GaussTacAgent.__init__`` gives ManiSkill)."""
    return core_urdf(cls) if cls.gausstac_core else cls.urdf_path


def collision_pieces(urdf, link):
    model = parse_urdf(urdf)
    out = []
    for g in model.geometry(link, "collision"):
        m = trimesh.load(str(model.mesh_path(g)), force="mesh") if g.kind == "mesh" else primitive_mesh(g)
        m.apply_transform(g.origin)
        out.append(m)
    return out


def inside(hull, points, margin=1e-9):
    """[N] bool: ``points`` inside the convex ``hull`` (every face plane)."""
    n = hull.face_normals
    d = np.einsum("ij,ij->i", n, hull.triangles[:, 0])
    return (points @ n.T <= d + margin).all(axis=1)


def built(cls, spec):
    with warnings.catch_warnings():
        warnings.simplefilter("error", ResolutionWarning)  # 4 mm = 4 cells: converged
        return pad_geometry(spec, cls.pad_urdf(), SPACING, DX)


@pytest.mark.parametrize("uid", list(TWINS))
def test_twin_is_registered_with_its_pads(uid):
    from mani_skill.agents.registration import REGISTERED_AGENTS

    cls = twin(uid)
    *_, stock, links = TWINS[uid]
    assert REGISTERED_AGENTS[uid].agent_cls is cls and cls.uid == uid
    assert issubclass(cls, GaussTacAgent) and issubclass(cls, REGISTERED_AGENTS[stock].agent_cls)
    assert {p.name: p.link for p in cls.gausstac_pads} == links
    for p in cls.gausstac_pads:  # 4 mm Dragon Skin 10 (the defaults)
        assert p.thickness == 4e-3 and p.material.E == pytest.approx(0.26e6, rel=0.05) and p.material.nu == 0.48
    assert not cls.gausstac_gaussians


def _on_contact_side(uid, spec, soft):
    """[N] bool: soft particles [m, link frame] on the side the hand touches with."""
    if uid == "dclaw_gausstac":  # palmar (+z on f1, -z on f2, f3), on the distal cylinder and cap
        return (soft[:, 2] * dclaw.DCLAW_PALMAR_Z[spec.link] > 0) & (soft[:, 0] > 0.045)
    if uid == "trifingerpro_gausstac":  # the sphere's inner side, below the stem, to just past the bottom
        return ((soft[:, 1] < 0) | (soft[:, 2] < -0.004)) & (soft[:, 1] < 0.0015) & (soft[:, 2] < 0.0085)
    return (soft[:, 0] > 0) & (soft[:, 2] > -0.035)  # Allegro: palmar, the distal 39 mm


@pytest.mark.parametrize("uid", list(TWINS))
def test_pads_build_at_the_default_resolution_on_the_contact_side(uid):
    cls = twin(uid)
    for spec in cls.gausstac_pads:
        pad = built(cls, spec)
        soft = pad.rest[~pad.kinematic]
        assert len(soft) > 5000 and pad.kinematic.sum() > 1000, (spec.name, pad.num_particles)
        centre = pad_mesh(spec, cls.pad_urdf()).center_mass
        axis = np.asarray(spec.axis)
        assert ((soft - centre) @ axis > 0).all(), spec.name  # the side the axis points to
        assert _on_contact_side(uid, spec, soft).all(), spec.name
        normal = pad.normal[pad.surface].mean(0)
        assert normal @ axis / np.linalg.norm(normal) > math.cos(math.radians(20)), spec.name
        # the taxel grid (centred on the sensor origin) covers the pad's surface
        s = pad.sensor_coords()[pad.surface]
        half = np.asarray(spec.layout.size) / 2 + pad.footprint / 2
        assert (np.abs(s[:, :2]) <= half).all(axis=1).mean() > 0.99, spec.name


@pytest.mark.parametrize("uid", list(TWINS))
def test_loaded_urdf_has_rigid_cores_below_the_pads(uid):
    cls = twin(uid)
    urdf = loaded_urdf(cls)
    *_, stock, _ = TWINS[uid]
    from mani_skill.agents.registration import REGISTERED_AGENTS

    assert set(link_names(urdf)) == set(link_names(REGISTERED_AGENTS[stock].agent_cls.urdf_path))
    for spec in cls.gausstac_pads:
        pieces = [m.convex_hull for m in collision_pieces(urdf, spec.link)]  # SAPIEN hulls each piece
        assert pieces
        pad = built(cls, spec)
        centre = pad_mesh(spec, cls.pad_urdf()).center_mass
        d = pad.rest - centre
        cos = d @ np.asarray(spec.axis) / np.linalg.norm(d, axis=1)
        # no rigid collision over the pad: its surface (within 80 % of the cone) is free, and
        # the rigid stop lies at least CORE_DEPTH of the layer deep
        free = pad.surface & (cos >= math.cos(math.radians(0.8 * spec.cone_deg)))
        soft = (~pad.kinematic & (pad.depth < CORE_DEPTH * spec.thickness - SPACING)
                & (cos >= math.cos(math.radians(0.8 * spec.cone_deg))))
        for m in pieces:
            assert not inside(m, pad.rest[free]).any(), spec.name
            assert inside(m, pad.rest[soft]).mean() < 0.02, spec.name


def test_dclaw_tip_hull_and_its_plate_and_brackets():
    cls = twin("dclaw_gausstac")
    hull = trimesh.load(dclaw.DCLAW_TIP_HULL, force="mesh")
    assert hull.is_watertight and hull.is_convex
    assert np.allclose(hull.bounds, [[0.033, -0.01, -0.01], [0.083, 0.01, 0.01]], atol=2e-4)
    stock = parse_urdf(dclaw.DCLAW_URDF)
    geoms = [[(g.kind, g.filename, tuple(np.round(g.origin[:3, 3], 6))) for g in stock.geometry(link, "collision")]
             for link in dclaw.DCLAW_PAD_LINKS.values()]
    assert geoms[0] == geoms[1] == geoms[2]  # one pad mesh for the three distal links
    for link in dclaw.DCLAW_PAD_LINKS.values():
        bounds = [np.round(m.bounds * 1e3, 1).tolist() for m in collision_pieces(cls.urdf_path, link)]
        assert [[23.5, -24.0, -13.0], [32.5, 24.0, 13.0]] in bounds  # the plate
        assert [[-2.0, 13.0, -12.0], [28.0, 23.0, 12.0]] in bounds  # the brackets
        assert [[-2.0, -23.0, -12.0], [28.0, -13.0, 12.0]] in bounds
        assert len(bounds) in (4, 5)  # the core (the inset, and the back when there is one), plate, brackets


def test_allegro_touch_twin_keeps_the_fsr_links():
    cls = twin("allegro_hand_right_touch_gausstac")
    stock = allegro_touch.TOUCH_URDF
    fsr = [n for n in link_names(stock) if "fsr" in n]
    assert len(fsr) == 16 and set(allegro_touch.FSR_LINKS) == set(fsr)
    urdf = loaded_urdf(cls)
    assert set(fsr) <= set(link_names(urdf))
    tips = set(allegro_touch.TIP_FSR_LINKS.values())
    a, b = parse_urdf(stock), parse_urdf(urdf)
    for name in fsr:
        (g,) = b.geometry(name, "collision")
        if name not in tips:  # the 12 FSRs off the fingertips: ManiSkill's box, unchanged
            (s,) = a.geometry(name, "collision")
            assert g.kind == s.kind == "box" and np.allclose(g.size, s.size) and np.allclose(g.origin, s.origin)
    # the tip FSRs lie under the pad's soft layer, on the rigid core (raised TIP_FSR_LIFT)
    for spec in cls.gausstac_pads:
        name = allegro_touch.TIP_FSR_LINKS[spec.link]
        joint = next(j for j in b.joints if j.child == name)
        assert joint.parent == spec.link
        (fsr_mesh,) = collision_pieces(urdf, name)
        fsr_mesh.apply_transform(joint.origin)  # -> the tip frame
        hull = pad_mesh(spec, cls.pad_urdf())
        depth = trimesh.proximity.signed_distance(hull, fsr_mesh.vertices)  # > 0 inside
        stop = CORE_DEPTH * spec.thickness - allegro_touch.TIP_FSR_LIFT
        assert depth.min() > stop - 0.3e-3 and (fsr_mesh.vertices[:, 0] > 0).all()
        stock_box = link_mesh(stock, name)
        stock_box.apply_transform(joint.origin)
        assert np.all(fsr_mesh.bounds[:, 2] >= stock_box.bounds[0, 2] - 1e-6)  # within its footprint
        assert np.all(fsr_mesh.bounds[:, 2] <= stock_box.bounds[1, 2] + 1e-6)


@pytest.mark.sapien
def test_twins_load_in_sapien():
    import gymnasium as gym
    import torch
    from mani_skill.utils.structs.pose import Pose

    for uid in TWINS:
        cls = twin(uid)
        env = gym.make("Empty-v1", robot_uids=uid, obs_mode="state_dict", sim_backend="physx_cpu",
                       control_mode="pd_joint_pos")
        try:
            obs, _ = env.reset(seed=0)
            agent = env.unwrapped.agent
            assert type(agent) is cls
            assert {p.link for p in cls.gausstac_pads} <= {link.name for link in agent.robot.get_links()}
            agent.robot.set_pose(Pose.create_from_pq(torch.tensor([0.0, 0.0, 0.5])))  # clear of the ground
            limits = agent.robot.get_qlimits()[0]  # (the Allegro thumb's joint_12.0 starts at 0.263 rad)
            q0 = agent.robot.get_qpos().clamp(limits[:, 0], limits[:, 1])
            active = [j.name for j in agent.robot.get_active_joints()]
            action = q0[0, [active.index(n) for n in agent.joint_names]].numpy()  # the controller's order
            for _ in range(10):
                obs, *_ = env.step(action)
            # no self-collision fights the drives (the D'Claw's plates and brackets stay on their links)
            assert torch.allclose(agent.robot.get_qpos(), q0, atol=0.02), uid
            if uid == "allegro_hand_right_touch_gausstac":
                assert [link.name for link in agent.fsr_links] == list(allegro_touch.FSR_LINKS)
                assert tuple(obs["agent"]["fsr_impulse"].shape) == (1, 16)
        finally:
            env.close()
