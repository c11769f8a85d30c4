"""The slab scatter's loop head (colours, ``scatter_tasks``, ``slab_range``, the slab's particles) is
written once, in :func:`~gausstac_maniskill.mpm.kernels.slabs.scatter_particles`; every particle
scatter passes it its per-particle ``ti.func``. A static check of the source (no Taichi run): the
bits and the compiled code are guarded by the state digests."""
import ast
import inspect

import gausstac_maniskill.mpm.kernels.contact
import gausstac_maniskill.mpm.kernels.grid
import gausstac_maniskill.mpm.kernels.launch
import gausstac_maniskill.mpm.kernels.pressure
import gausstac_maniskill.mpm.kernels.readouts
import gausstac_maniskill.mpm.kernels.slabs
import gausstac_maniskill.mpm.kernels.transfer

MODULES = [gausstac_maniskill.mpm.kernels.slabs, gausstac_maniskill.mpm.kernels.grid,
           gausstac_maniskill.mpm.kernels.transfer, gausstac_maniskill.mpm.kernels.contact,
           gausstac_maniskill.mpm.kernels.pressure, gausstac_maniskill.mpm.kernels.readouts,
           gausstac_maniskill.mpm.kernels.launch]
SCATTERS = {"p2g": "p2g_particle", "volume_scatter": "volume_particle", "contact_scatter": "contact_particle"}


def _calls(fn: ast.FunctionDef) -> list[ast.Call]:
    return [n for n in ast.walk(fn) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)]


def _functions() -> dict[str, ast.FunctionDef]:
    out = {}
    for mod in MODULES:
        for fn in ast.walk(ast.parse(inspect.getsource(mod))):
            if isinstance(fn, ast.FunctionDef):
                out[fn.name] = fn
    return out


def test_the_slab_loop_head_is_written_once():
    users = sorted(name for name, fn in _functions().items()
                   if any(c.func.id in ("scatter_tasks", "slab_range") for c in _calls(fn)))
    assert users == ["scatter_particles"]


def test_every_particle_scatter_runs_through_scatter_particles():
    funcs = _functions()
    for scatter, body in SCATTERS.items():
        calls = [c for c in _calls(funcs[scatter]) if c.func.id == "scatter_particles"]
        assert len(calls) == 1, scatter
        assert isinstance(calls[0].args[-1], ast.Name) and calls[0].args[-1].id == body, scatter
        assert body in funcs, body
