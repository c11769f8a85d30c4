"""The MPM solver's parts fit together: the world is composed of its builder, state, stepper and
readouts over an immutable model, the kernel package re-exports its modules' names, and the record layouts agree with
each other (static checks, no Taichi launch)."""
import ast
import importlib
import inspect
from pathlib import Path

import gausstac_maniskill.mpm.kernels as K
from gausstac_maniskill.mpm import building, readouts, state, stepper
from gausstac_maniskill.mpm.solver import MPMWorld

KERNEL_MODULES = ["layout", "slabs", "grid", "transfer", "contact", "pressure", "readouts", "launch"]


def test_the_world_is_composed_of_its_parts():
    for part in (building.WorldBuilder, readouts.WorldReadouts, stepper.WorldStepper, state.WorldState):
        assert issubclass(MPMWorld, part)
    own = [n for n, v in vars(MPMWorld).items() if inspect.isfunction(v)]
    for part in (building.WorldBuilder, readouts.WorldReadouts, stepper.WorldStepper, state.WorldState):
        twice = set(own) & set(vars(part))
        assert not twice, f"{part.__name__} and MPMWorld both define {twice}"


def test_the_parts_do_not_import_the_facade():
    """Layering: solver.py composes the parts; no part imports solver.py (or a later part)."""
    later = {"model": {"solver", "state", "building", "stepper", "readouts"},
             "state": {"solver", "building", "stepper", "readouts"},
             "building": {"solver", "stepper", "readouts"}, "stepper": {"solver", "building", "readouts"},
             "readouts": {"solver", "building"}}
    for name, banned in later.items():
        tree = ast.parse(Path(importlib.import_module(f"gausstac_maniskill.mpm.{name}").__file__).read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                assert (node.module or "").split(".")[0] not in banned, f"mpm/{name}.py imports .{node.module}"


def test_the_kernel_package_re_exports_every_public_name():
    for m in KERNEL_MODULES:
        mod = importlib.import_module(f"gausstac_maniskill.mpm.kernels.{m}")
        tree = ast.parse(Path(mod.__file__).read_text())
        defined = [n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))]
        defined += [t.id for n in tree.body if isinstance(n, ast.Assign) for t in ast.walk(n.targets[0])
                    if isinstance(t, ast.Name)]
        for name in defined:
            assert getattr(K, name) is getattr(mod, name), f"kernels.{name} is not kernels.{m}.{name}"


def test_particle_fields_cover_the_particle_pack():
    """Every member of the kernels' Particles pack is a documented per-particle field of the state,
    with the same row shape and scalar type."""
    for name, nd in K.Particles.members.items():
        assert name in state.PARTICLE_FIELDS, f"Particles.{name} is not in state.PARTICLE_FIELDS"
        d = nd.dtype
        ndim = getattr(d, "ndim", 0)
        row = () if not ndim else ((d.n,) if ndim == 1 else (d.n, d.m))
        field = state.PARTICLE_FIELDS[name]
        assert field.row == row, f"{name}: row {field.row}, the pack's {row}"
        assert field.dtype == (d.dtype if ndim else d), f"{name}: dtype {field.dtype}, the pack's"
    assert set(state._STATE_FIELDS) <= set(state.PARTICLE_FIELDS)


def test_substep_switches_follow_the_advance_kernel():
    """:class:`kernels.Flags` lists :func:`kernels.advance`'s compile-time switches in its order
    (MPMWorld._advance_flags passes them positionally)."""
    tree = ast.parse(Path(K.launch.__file__).read_text())
    advance = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "advance")
    assert list(K.Flags._fields) == [a.arg for a in advance.args.args][2:]
    assert all(v is None for v in K.ActiveBox())
