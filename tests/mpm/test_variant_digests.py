"""Refactor guard for the MPM kernels' compile-time variants that the pad scene of
``tests/test_state_digest.py`` does not take: grid-node contact, the implicit cell pressure,
two velocity fields, no F-bar, the active patch (CPU slab scatter). The state after a few
steps of each is compared with a digest recorded per machine key (the same key as that test:
the bits depend on the instruction set and the compile mode); without one the test skips:

    GAUSSTAC_COMPILE=fast python tests/mpm/test_variant_digests.py --record

Digested: positions, velocities, F, stresses, contact forces and the link's wrench (the
energies and the grid contact's collider sums are atomic float sums, not bit-reproducible).
"""
from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

DIGESTS = Path(__file__).with_name("data") / "variant_digests.json"


def machine_key() -> str:
    """tests/test_state_digest.py's machine key."""
    spec = importlib.util.spec_from_file_location("_state_digest", Path(__file__).parents[1] / "test_state_digest.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.machine_key()


def _world(contact="particle", **settings):
    from gausstac_maniskill.config import Material, SolverSettings
    from gausstac_maniskill.mpm import MPMWorld, box_particles

    dx = 1.5e-3
    s = SolverSettings(**{"dx": dx, "gravity": (0.0, 0.0, -9.81), "max_substeps": 2000, **settings})
    world = MPMWorld(s, contact=contact)
    world.add_link("base", np.eye(4))
    pts = box_particles([-0.006, -0.006, -0.006], [0.006, 0.006, 0.0], s.particle_spacing)
    world.add_group("pad", pts, Material(E=3e5, nu=0.45, density=1100.0), link="base",
                    kinematic=pts[:, 2] < -0.006 + 2 * dx)
    return world


def _press(world, soft=False) -> str:
    """A sphere pressed and dragged into the pad (with ``soft``, onto a soft block of the other
    field lying on it) while the pad's link slides: 6 control steps of 4 ms."""
    from gausstac_maniskill.config import Material
    from gausstac_maniskill.mpm import Sphere, box_particles
    from gausstac_maniskill.transforms import make_pose

    z0 = 4.5e-3
    if soft:
        pts = box_particles([-0.003, -0.003, 0.0008], [0.003, 0.003, 0.005], world.settings.particle_spacing)
        world.add_group("sponge", pts, Material(E=5e4, nu=0.3, density=200.0), field=1)
        z0 += 6e-3
    c = world.add_collider(Sphere(radius=4e-3, pose=make_pose([0.0, 0.0, z0]), friction=0.4))
    for k in range(6):
        world.set_collider_pose(c, make_pose([1e-4 * k, 0.0, z0 - 0.25e-3 * (k + 1)]))
        T = np.eye(4)
        T[0, 3] = 2e-5 * k
        world.set_link_pose("base", T)
        world.step(4e-3)
    h = hashlib.sha256()
    for a in (world.positions(), world.velocities(), world.deformation_gradients(), world.stresses(),
              world.contact_forces(), *world.link_wrench("base")):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


SCENES = {
    "grid_contact": lambda: _press(_world("grid")),
    "implicit_pressure": lambda: _press(_world(pressure="implicit")),
    "two_fields": lambda: _press(_world(), soft=True),
    "no_fbar": lambda: _press(_world(fbar=False)),
    "patch": lambda: _press(_world(patch_radius=4e-3)),
}


def recorded() -> dict:
    return json.loads(DIGESTS.read_text()) if DIGESTS.exists() else {}


@pytest.fixture
def slab_scatter(monkeypatch):
    monkeypatch.setenv("GAUSSTAC_SCATTER", "slabs")


@pytest.mark.parametrize("scene", list(SCENES))
def test_variant_is_bit_identical_to_the_recorded_digest(scene, slab_scatter):
    key = machine_key()
    expected = recorded().get(key, {}).get(scene)
    if expected is None:
        pytest.skip(f"no digest recorded for {scene!r} on {key}: run "
                    "`GAUSSTAC_COMPILE=fast python tests/mpm/test_variant_digests.py --record`")
    assert SCENES[scene]() == expected, (
        f"{scene}: the state differs from the recorded digest; if the change is meant to change the "
        "arithmetic, record new digests (see this module's docstring) and say so in the commit")


if __name__ == "__main__":
    if "--record" not in sys.argv:
        raise SystemExit(__doc__)
    os.environ["GAUSSTAC_SCATTER"] = "slabs"
    only = [a for a in sys.argv[1:] if a in SCENES] or list(SCENES)
    data = recorded()
    key = machine_key()
    for name in only:
        data.setdefault(key, {})[name] = SCENES[name]()
        print(f"{name}: {data[key][name]}")
    DIGESTS.parent.mkdir(exist_ok=True)
    DIGESTS.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    print("wrote", DIGESTS, "for", key)
