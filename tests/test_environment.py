"""Environment variables read in one place (environment.py) and the disk cache's folders (cache.py)."""
import ast
import pathlib

import numpy as np
import pytest

from gausstac_maniskill import cache, environment

ROOT = pathlib.Path(__file__).resolve().parents[1]
SOURCES = [p for folder in ("gausstac_maniskill", "agents", "tasks", "assets") for p in (ROOT / folder).rglob("*.py")]


def test_read_follows_os_environ_at_each_call(monkeypatch):
    monkeypatch.delenv("GAUSSTAC_ARCH", raising=False)
    assert environment.read("GAUSSTAC_ARCH") == "auto"
    monkeypatch.setenv("GAUSSTAC_ARCH", "cpu")
    assert environment.read("GAUSSTAC_ARCH") == "cpu"
    with pytest.raises(KeyError, match="GAUSSTAC_NO_SUCH.*VARIABLES"):
        environment.read("GAUSSTAC_NO_SUCH")


def test_every_variable_is_in_the_table_and_read_nowhere_else():
    """Guards the one place: no module but environment.py touches ``os.environ`` (or
    ``os.getenv``), every name read through it is in VARIABLES, and the docstring lists them all."""
    touching, names = [], set()
    for path in SOURCES:
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if (isinstance(node, ast.Attribute) and node.attr in ("environ", "getenv", "putenv")
                    and isinstance(node.value, ast.Name) and node.value.id == "os"):
                touching.append(f"{path.relative_to(ROOT)}:{node.lineno}")
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.args
                    and node.func.attr in ("read", "write", "write_default")
                    and isinstance(node.func.value, ast.Name) and node.func.value.id == "environment"
                    and isinstance(node.args[0], ast.Constant)):
                names.add(node.args[0].value)
    assert [t for t in touching if not t.startswith("gausstac_maniskill/environment.py")] == []
    assert names and names <= set(environment.VARIABLES)
    assert all(f"``{name}``" in environment.__doc__ for name in environment.VARIABLES)


def test_cache_root_and_its_folders(monkeypatch, tmp_path):
    monkeypatch.setenv("GAUSSTAC_CACHE", str(tmp_path))
    assert cache.root() == tmp_path and cache.folder(cache.SDFS) == tmp_path / "sdfs"
    assert cache.cache_dir(cache.CORES, "k").is_dir() and cache.cache_path("cores") == tmp_path / "cores"
    monkeypatch.setenv("GAUSSTAC_CACHE", "off")
    assert cache.root() is None and cache.folder(cache.COMPLIANCES) is None
    assert cache.cache_path("cores").parent.name == "gausstac_maniskill"  # in the temporary folder
    monkeypatch.setenv("GAUSSTAC_CACHE", "")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache.root() == tmp_path / "xdg" / "gausstac_maniskill"
    computed = []

    def compute():
        computed.append(1)
        return np.ones(2, np.float32)

    got = cache.cached_array("test", "a thing", "stem", (2,), compute)
    again = cache.cached_array("test", "a thing", "stem", (2,), lambda: pytest.fail("computed again"))
    assert computed == [1] and (got == again).all() and (tmp_path / "xdg/gausstac_maniskill/test/stem.npy").is_file()
