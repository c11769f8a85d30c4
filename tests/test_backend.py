"""The single ti.init: arch names, CUDA asked for on a machine without it, compile switches."""
import ast
import os
import pathlib
import subprocess
import sys

import pytest

from gausstac_maniskill import backend
from gausstac_maniskill.errors import GaussTacError  # noqa: F401  (import check)


def test_unknown_arch_is_refused():
    with pytest.raises(backend.BackendError, match="vulkan"):
        backend.init("vulkan")


def test_cannot_switch_arch_after_init():
    assert backend.current_arch() == "cpu"
    assert backend.init("auto") == "cpu"
    if backend.current_arch() == "cpu":
        with pytest.raises(backend.BackendError, match="already initialised"):
            backend.init("cuda")


def test_cuda_request_on_cpu_machine_gives_clear_error():
    code = ("from gausstac_maniskill import backend\n"
            "try:\n    backend.init('cuda')\n    print('CUDA-OK')\n"
            "except backend.BackendError as e:\n    print('ERR', e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    if "CUDA-OK" in out.stdout:
        pytest.skip("this machine has CUDA")
    assert "ERR backend arch='cuda' was requested but no working CUDA device" in out.stdout, out.stdout + out.stderr
    assert "Traceback" not in out.stderr


@pytest.mark.parametrize("build, cfg, opt", [("", "False", "1"), ("fast", "False", "0"),
                                             ("taichi", "True", "1"), ("bogus", None, None)])
def test_compile_builds_reach_taichi(build, cfg, opt):
    """Guards the wiring of backend._compile_options (not physics): the product build turns
    Taichi's CFG pass off, ``GAUSSTAC_COMPILE=fast`` also its whole-kernel CSE (opt_level 0),
    ``taichi`` keeps Taichi's defaults, another value is refused by name; the offline cache
    may grow to 1 GiB. In a child process: Taichi starts once per process."""
    code = ("import taichi as ti\nfrom gausstac_maniskill import backend\n"
            "try:\n    backend.init('cpu')\nexcept backend.BackendError as e:\n    print('ERR', e)\n    raise SystemExit\n"
            "c = ti.lang.impl.current_cfg()\n"
            "print(c.cfg_optimization, c.opt_level, c.offline_cache_max_size_of_files)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "GAUSSTAC_COMPILE": build})
    if cfg is None:
        assert "ERR GAUSSTAC_COMPILE='bogus' is not one of" in out.stdout, out.stdout + out.stderr
    else:
        assert out.stdout.split()[-3:] == [cfg, opt, str(1 << 30)], out.stdout + out.stderr


_CORES = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 1


@pytest.mark.skipif(_CORES < 2, reason="pinning needs a process that may use 2 or more cores")
@pytest.mark.parametrize("threads, pin, pinned", [(_CORES, "", True), (_CORES, "0", False), (1, "", False)])
def test_cpu_pool_workers_pinned_one_per_core(threads, pin, pinned):
    """Guards the wiring of cpu_pinning (not physics; the speed it buys is in BENCHMARKS.md): a
    pool with one worker per core has its workers pinned to distinct cores, all of them;
    ``GAUSSTAC_CPU_PIN=0`` or a smaller pool (process collection) leaves every thread free."""
    code = ("import os\nfrom gausstac_maniskill import backend\nbackend.init('cpu')\n"
            "print(sorted(tuple(sorted(os.sched_getaffinity(int(t)))) for t in os.listdir('/proc/self/task')))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "GAUSSTAC_CPU_THREADS": str(threads), "GAUSSTAC_CPU_PIN": pin})
    masks = ast.literal_eval(out.stdout.strip().splitlines()[-1])
    single = sorted(m for m in masks if len(m) == 1)
    if pinned:
        assert single == sorted((c,) for c in os.sched_getaffinity(0)), out.stdout + out.stderr
    else:
        assert single == [], out.stdout + out.stderr


def _static(loop) -> bool:
    return isinstance(loop, ast.For) and "static" in ast.unparse(loop.iter)


def _names(node) -> set:
    return {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}


def _additions(body, static_vars=frozenset()):
    """(target, the enclosing static loops' variables its index leaves out, its index's names,
    whether it is a plain ``x[i] = x[i] + ..``) of each addition to an array entry in ``body``:
    ``x[i] += ..``, ``ti.atomic_add(x[i], ..)`` or ``x[i] = x[i] ..``, through ifs and static
    loops (each run-time loop is checked on its own)."""
    found = []
    for st in body:
        target = st.target if isinstance(st, ast.AugAssign) else None
        plain = False
        if isinstance(st, ast.Expr) and isinstance(st.value, ast.Call) and ast.unparse(st.value.func).endswith("atomic_add"):
            target = st.value.args[0]
        if isinstance(st, ast.Assign) and len(st.targets) == 1 and isinstance(st.targets[0], ast.Subscript) \
                and ast.unparse(st.targets[0]) in {ast.unparse(n) for n in ast.walk(st.value)}:
            target, plain = st.targets[0], True
        if isinstance(target, ast.Subscript):
            index = _names(target)
            found.append((ast.unparse(target), static_vars - index, index, plain))
        elif isinstance(st, ast.If):
            found += _additions(st.body, static_vars) + _additions(st.orelse, static_vars)
        elif _static(st):
            found += _additions(st.body, static_vars | _names(st.target))
    return found


def repeated_additions(source: str) -> list[str]:
    """Where a Taichi kernel or func, inside a run-time loop nested in the kernel's parallel loop,
    adds twice per iteration to one array entry (two ``x[i] += ..`` or ``ti.atomic_add(x[i], ..)``
    of the same text, or one inside a static loop whose variable its index leaves out), or reads
    and writes back an entry the loop does not index (``x[i] = x[i] + ..``, ``i`` not set in the
    loop). Taichi 1.7.4 at ``opt_level=0`` (GAUSSTAC_COMPILE=fast, ``make test``'s build) keeps
    only the first addition of an iteration, and reads such an entry once before the loop; the
    product build sums them all. Local variables are not
    affected."""
    hits = []

    def walk(body, depth, name, local):
        """``local``: the function's local variables and matrices (not affected)."""
        for st in body:
            if isinstance(st, (ast.For, ast.While)) and not _static(st):
                if depth >= 1:
                    adds = _additions(st.body)
                    texts = [t for t, *_ in adds]
                    varying = _names(st.target) if isinstance(st, ast.For) else set()
                    varying |= {t.id for a in ast.walk(st) if isinstance(a, (ast.Assign, ast.AugAssign))
                                for t in (a.targets if isinstance(a, ast.Assign) else [a.target]) if isinstance(t, ast.Name)}
                    hits.extend(f"{name}, line {st.lineno}: {t}" for t, missed, index, plain in adds
                                if t.split("[")[0] not in local
                                and (missed or texts.count(t) > 1 or (plain and not index & varying)))
                walk(st.body, depth + 1, name, local)
            elif isinstance(st, (ast.For, ast.If, ast.With)):
                walk(st.body, depth, name, local)
                walk(getattr(st, "orelse", []), depth, name, local)

    for fn in ast.walk(ast.parse(source)):
        decorators = " ".join(ast.unparse(d) for d in getattr(fn, "decorator_list", []))
        if isinstance(fn, ast.FunctionDef) and ("kernel" in decorators or "func" in decorators):
            local = {t.id for a in ast.walk(fn) if isinstance(a, ast.Assign) for t in a.targets if isinstance(t, ast.Name)}
            walk(fn.body, 0 if "kernel" in decorators else 1, fn.name, local)  # a func runs inside a kernel's loop
    return hits


def test_the_repeated_addition_scan_finds_the_pattern():
    """Guards the scan below (it can fail): the patterns Taichi's fast build sums wrongly are found,
    one addition per entry and iteration is not."""
    bad = ("@ti.kernel\ndef k(x: A, out: A):\n    for e in range(4):\n        for q in range(5):\n"
           "            out[e] += x[e, q]\n            ti.atomic_add(out[e], 2.0 * x[e, q])\n"
           "            for j in ti.static(range(3)):\n                out[e + 1] += x[e, q] * j\n"
           "            H = ti.Matrix.zero(ti.f64, 3, 3)\n            for a in ti.static(range(3)):\n"
           "                H[0, 0] += x[e, a]\n"
           "            out[e + 2] = out[e + 2] + x[e, q]\n")
    good = ("@ti.kernel\ndef k(x: A, out: A):\n    for e in range(4):\n        out[e] += 1.0\n        out[e] += 2.0\n"
            "        for q in range(5):\n            for j in ti.static(range(3)):\n                out[e, j] += x[e, q]\n"
            "            i = q + 1\n            out[i] = out[i] + x[e, q]\n")
    assert repeated_additions(bad) == ["k, line 4: out[e]", "k, line 4: out[e]", "k, line 4: out[e + 1]", "k, line 4: out[e + 2]"]
    assert repeated_additions(good) == []


def test_no_kernel_adds_twice_to_one_entry_in_an_inner_loop():
    """Guards that ``make test``'s fast build computes what the product computes: no kernel or func
    of the package adds twice to one array entry per iteration of an inner run-time loop
    (:func:`repeated_additions`, a Taichi 1.7.4 miscompile at opt_level=0)."""
    root = pathlib.Path(backend.__file__).resolve().parent
    files = sorted(root.rglob("*.py")) + sorted((root.parent / "tasks").rglob("*.py")) + sorted((root.parent / "agents").rglob("*.py"))
    hits = [f"{path.name}: {hit}" for path in files for hit in repeated_additions(path.read_text())]
    assert hits == []
