"""Bad inputs to the MPM world: clear errors naming the field, nothing lost."""
import numpy as np
import pytest
import trimesh

from gausstac_maniskill.config import Material, SolverSettings
from gausstac_maniskill.errors import AssetError, ConfigError
from gausstac_maniskill.mpm import MeshCollider, MPMWorld, Sphere, box_particles, mesh_particles


def test_empty_particle_set():
    world = MPMWorld(SolverSettings(mass_scaling=1.0, max_substeps=2000))
    with pytest.raises(ConfigError, match=r"add_group\('pad'\): positions is empty"):
        world.add_group("pad", np.zeros((0, 3)), Material(E=3.0e5, nu=0.45, density=1100.0))


def test_nan_positions_and_bad_shapes():
    world = MPMWorld(SolverSettings(mass_scaling=1.0, max_substeps=2000))
    with pytest.raises(ConfigError, match="NaN"):
        world.add_group("pad", np.full((4, 3), np.nan), Material(E=3.0e5, nu=0.45, density=1100.0))
    with pytest.raises(ConfigError, match=r"shape \[N, 3\]"):
        world.add_group("pad", np.zeros((4, 2)), Material(E=3.0e5, nu=0.45, density=1100.0))


def test_unknown_link_is_named():
    world = MPMWorld(SolverSettings(mass_scaling=1.0, max_substeps=2000))
    world.add_link("link_3.0_tip", np.eye(4))
    pts = box_particles([0, 0, 0], [0.004] * 3, 1e-3)
    with pytest.raises(ConfigError, match=r"unknown link 'link_3.0_tipp'.*link_3.0_tip"):
        world.add_group("pad", pts, Material(E=3.0e5, nu=0.45, density=1100.0), link="link_3.0_tipp", kinematic=True)
    with pytest.raises(ConfigError, match="unknown link"):
        world.set_link_pose("palm", np.eye(4))


def test_non_rigid_or_nan_pose():
    world = MPMWorld(SolverSettings(mass_scaling=1.0, max_substeps=2000))
    world.add_link("tip", np.eye(4))
    bad = np.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(ConfigError, match="not a rotation"):
        world.set_link_pose("tip", bad)
    nan = np.eye(4)
    nan[0, 3] = np.nan
    with pytest.raises(ConfigError, match=r"pose of link 'tip' contains NaN"):
        world.set_link_pose("tip", nan)


def test_bad_step_length():
    world = MPMWorld(SolverSettings(mass_scaling=1.0, max_substeps=2000))
    for dt in (0.0, -1e-3, float("nan")):
        with pytest.raises(ConfigError, match="dt must be a positive"):
            world.step(dt)


def test_collider_mesh_not_watertight():
    mesh = trimesh.creation.box(extents=(0.01, 0.01, 0.01))
    mesh.faces = mesh.faces[:-2]  # punch a hole
    with pytest.raises(AssetError, match="not watertight"):
        MeshCollider(mesh=mesh, name="cube")


def test_collider_mesh_missing_file(tmp_path):
    with pytest.raises(AssetError, match=r"missing\.obj: mesh file not found"):
        MeshCollider(mesh=str(tmp_path / "missing.obj"))


def test_collider_bad_size_and_friction():
    with pytest.raises(ConfigError, match=r"Sphere\.radius"):
        Sphere(radius=-1.0)
    with pytest.raises(ConfigError, match=r"ball\.friction"):
        Sphere(radius=0.01, friction=-0.1, name="ball")


def test_pad_mesh_not_watertight():
    mesh = trimesh.creation.icosphere(2, radius=0.01)
    mesh.faces = mesh.faces[1:]
    with pytest.raises(AssetError, match="fingertip.*not watertight"):
        mesh_particles(mesh, 1e-3, name="fingertip")


def test_mesh_too_small_for_spacing():
    with pytest.raises(AssetError, match="no particle fits"):
        mesh_particles(trimesh.creation.icosphere(2, radius=1e-4), 1e-3, name="grain")


def test_bad_bond_surface_is_named():
    world = MPMWorld(SolverSettings(mass_scaling=1.0, max_substeps=2000))
    world.add_link("base", np.eye(4))
    pts = box_particles([0, 0, 0], [0.004] * 3, 5e-4)
    kin = pts[:, 2] < 1e-3
    with pytest.raises(ConfigError, match=r"add_group\('pad'\): give bond_distance and bond_normal together"):
        world.add_group("pad", pts, Material(E=3.0e5, nu=0.45, density=1100.0), link="base", kinematic=kin, bond_distance=pts[:, 2] - 1e-3)
    with pytest.raises(ConfigError, match=r"add_group\('pad'\): bond_normal must be unit vectors"):
        world.add_group("pad", pts, Material(E=3.0e5, nu=0.45, density=1100.0), link="base", kinematic=kin, bond_distance=pts[:, 2] - 1e-3,
                        bond_normal=[0.0, 0.0, 2.0])
    with pytest.raises(ConfigError, match=r"add_group\('pad'\): bond_distance / bond_normal contain NaN"):
        world.add_group("pad", pts, Material(E=3.0e5, nu=0.45, density=1100.0), link="base", kinematic=kin, bond_distance=np.nan,
                        bond_normal=[0.0, 0.0, 1.0])
    with pytest.raises(ConfigError, match=r"SolverSettings.bond='glue' must be 'surface' or 'nodes'"):
        SolverSettings(bond="glue", mass_scaling=1.0, max_substeps=2000)
    with pytest.raises(ConfigError, match=r"SolverSettings.pressure='sometimes' must be 'explicit' or 'implicit'"):
        SolverSettings(pressure="sometimes", mass_scaling=1.0, max_substeps=2000)
    with pytest.raises(ConfigError, match=r"SolverSettings.pressure_iterations=0 must be an integer in 1..200"):
        SolverSettings(pressure_iterations=0, mass_scaling=1.0, max_substeps=2000)
    world.add_group("pad", pts, Material(E=3.0e5, nu=0.45, density=1100.0), link="base", kinematic=kin)  # nothing was lost: the name is free


def test_default_bond_of_a_flat_layer_is_exact():
    """Without bond_distance/bond_normal the bond is estimated from the kinematic mask: for a
    flat bond on the particle lattice, the plane between the last bound and first free layer."""
    world = MPMWorld(SolverSettings(mass_scaling=1.0, max_substeps=2000))
    world.add_link("base", np.eye(4))
    h = 5e-4
    pts = box_particles([0, 0, 0], [0.004] * 3, h)
    z_bond = 1e-3
    world.add_group("pad", pts, Material(E=3.0e5, nu=0.45, density=1100.0), link="base", kinematic=pts[:, 2] < z_bond)
    bond = world._host_parts.bond
    kin = pts[:, 2] < z_bond
    np.testing.assert_allclose(bond[kin, 3], pts[kin, 2] - z_bond, atol=1e-7)
    np.testing.assert_allclose(bond[kin, :3], np.tile([0.0, 0.0, 1.0], (kin.sum(), 1)), atol=1e-6)
    assert not bond[~kin].any()
