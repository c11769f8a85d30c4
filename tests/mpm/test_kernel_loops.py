"""Every loop of a Taichi kernel that should run in parallel does.

Taichi parallelises only the loops at a kernel's outermost scope. A loop that a run-time
``if`` (or ``while``) encloses runs serially, on one thread: on a GPU that can dominate a
step's kernel time, which no CPU test shows (``bench kernels --arch cuda`` measures it).

This is a static check of the source (no Taichi run): it walks each kernel, inlines the
``ti.func`` it calls, and reports a loop reached through a run-time branch. A loop meant to
be serial says so with ``ti.loop_config(serialize=True)`` right before it. It guards the code
path, not the physics: the physics tests do not see how many threads ran."""
import ast
import inspect

import pytest

import gausstac_maniskill.geometry.colliders
import gausstac_maniskill.geometry.mesh_query
import gausstac_maniskill.mpm.colliders
import gausstac_maniskill.mpm.kernels.contact
import gausstac_maniskill.mpm.kernels.grid
import gausstac_maniskill.mpm.kernels.launch
import gausstac_maniskill.mpm.kernels.layout
import gausstac_maniskill.mpm.kernels.pressure
import gausstac_maniskill.mpm.kernels.readouts
import gausstac_maniskill.mpm.kernels.slabs
import gausstac_maniskill.mpm.kernels.transfer
import gausstac_maniskill.mpm.patch
import gausstac_maniskill.splat.kernels.common
import gausstac_maniskill.splat.kernels.composite
import gausstac_maniskill.splat.kernels.project
import gausstac_maniskill.splat.kernels.tiles

MODULES = [gausstac_maniskill.mpm.kernels.layout, gausstac_maniskill.mpm.kernels.slabs,
           gausstac_maniskill.mpm.kernels.grid, gausstac_maniskill.mpm.kernels.transfer,
           gausstac_maniskill.mpm.kernels.contact, gausstac_maniskill.mpm.kernels.pressure,
           gausstac_maniskill.mpm.kernels.readouts, gausstac_maniskill.mpm.kernels.launch,
           gausstac_maniskill.mpm.patch, gausstac_maniskill.mpm.colliders,
           gausstac_maniskill.geometry.colliders, gausstac_maniskill.geometry.mesh_query,
           gausstac_maniskill.splat.kernels.common, gausstac_maniskill.splat.kernels.project,
           gausstac_maniskill.splat.kernels.tiles, gausstac_maniskill.splat.kernels.composite]


def _decorated(fn: ast.FunctionDef, name: str) -> bool:
    """``fn`` carries ``@ti.<name>`` (``@ti.kernel``, ``@ti.func``)."""
    return any(isinstance(d, ast.Attribute) and d.attr == name for d in fn.decorator_list)


def _is_static(node) -> bool:
    """``ti.static(...)``: resolved at compile time (a static ``if`` or an unrolled loop)."""
    return (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "static")


def _serialize_marker(stmt) -> bool:
    """``ti.loop_config(serialize=True)``: the next loop is serial on purpose."""
    call = stmt.value if isinstance(stmt, ast.Expr) else None
    return (isinstance(call, ast.Call) and isinstance(call.func, ast.Attribute) and call.func.attr == "loop_config"
            and any(k.arg == "serialize" and isinstance(k.value, ast.Constant) and k.value.value for k in call.keywords))


class _Walker:
    """Walks one kernel; ``found`` lists the serial loops as ``kernel > func: line``."""

    def __init__(self, funcs: dict[str, tuple[str, ast.FunctionDef]]):
        self.funcs, self.found = funcs, []

    def body(self, stmts, path, branch: bool) -> None:
        """Statements at the kernel's outermost scope; ``branch``: under a run-time if/while."""
        serialize = False
        for s in stmts:
            if isinstance(s, ast.For):
                if _is_static(s.iter):  # unrolled: its body stays at the outermost scope
                    self.body(s.body, path, branch)
                elif branch and not serialize:
                    self.found.append(f"{' > '.join(path)}: line {s.lineno}")
            elif isinstance(s, ast.If):
                self.body(s.body, path, branch or not _is_static(s.test))
                self.body(s.orelse, path, branch or not _is_static(s.test))
            elif isinstance(s, ast.While):
                self.body(s.body, path, True)
            else:
                self.calls(s, path, branch)
            serialize = _serialize_marker(s)

    def calls(self, stmt, path, branch: bool) -> None:
        """Inline the ``ti.func`` that ``stmt`` calls (at the outermost scope, as Taichi does)."""
        for node in ast.walk(stmt):
            if isinstance(node, ast.Call):
                name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", None)
                if name in self.funcs and name not in path:
                    self.body(self.funcs[name][1].body, path + [name], branch)


def _sources():
    funcs, kernels = {}, []
    for mod in MODULES:
        tree = ast.parse(inspect.getsource(mod))
        for fn in ast.walk(tree):
            if isinstance(fn, ast.FunctionDef):
                if _decorated(fn, "func"):
                    funcs.setdefault(fn.name, (mod.__name__, fn))
                elif _decorated(fn, "kernel"):
                    kernels.append((mod.__name__, fn))
    return funcs, kernels


FUNCS, KERNELS = _sources()


@pytest.mark.parametrize("module,kernel", KERNELS, ids=[f"{m.split('.')[-1]}.{k.name}" for m, k in KERNELS])
def test_no_kernel_loop_is_serialised_by_a_runtime_branch(module, kernel):
    walker = _Walker(FUNCS)
    walker.body(kernel.body, [kernel.name], False)
    assert not walker.found, (f"{module}.{kernel.name}: loops under a run-time if/while run serially (one GPU "
                              f"thread); make the branch a loop count or ti.static, or mark the loop "
                              f"ti.loop_config(serialize=True): {walker.found}")


def test_the_check_finds_a_loop_under_a_runtime_if():
    """The walker on the shape of the bug it guards (a parallel loop in a ``ti.func`` called
    under a run-time ``if``)."""
    src = '''
@ti.func
def ghosts(n: ti.template(), v: ti.template()):
    for i in range(n):
        v[i] = 0.0

@ti.kernel
def advance(on: ti.i32):
    for k in ti.static(range(2)):
        if ti.static(k == 0):
            ghosts(8, v)
    if on > 0:
        ghosts(8, v)
    n = ti.select(on > 0, 8, 0)
    ghosts(n, v)
    if on > 0:
        ti.loop_config(serialize=True)
        for i in range(3):
            pass
'''
    tree = ast.parse(src)
    funcs = {f.name: ("src", f) for f in tree.body if _decorated(f, "func")}
    walker = _Walker(funcs)
    kernel = next(f for f in tree.body if _decorated(f, "kernel"))
    walker.body(kernel.body, [kernel.name], False)
    assert walker.found == ["advance > ghosts: line 4"]
