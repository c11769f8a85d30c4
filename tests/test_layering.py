"""The import graph keeps its layering: no cycles between components, nothing imported from a
higher layer, and the two pad solvers (fem, mpm) independent of each other.

It reads the source with ``ast`` (scripts/import_graph.py), imports included that sit inside
functions. It guards the structure, not the physics."""
import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("import_graph", ROOT / "scripts" / "import_graph.py")
import_graph = importlib.util.module_from_spec(spec)
spec.loader.exec_module(import_graph)


def test_components_form_no_cycle_and_follow_the_layers():
    graph = import_graph.component_graph(ROOT)
    assert {"fem", "mpm", "geometry", "cosim", "tasks"} <= set(graph)  # the scan found the package
    assert import_graph.cycles(graph) == []
    assert import_graph.against_layers(graph) == []


def test_every_component_has_a_layer():
    graph = import_graph.component_graph(ROOT)
    assert sorted(set(graph) - set(import_graph.LAYERS)) == []


def test_the_pad_solvers_do_not_import_each_other():
    graph = import_graph.component_graph(ROOT)
    assert "mpm" not in graph["fem"] and "fem" not in graph["mpm"]


def test_the_scan_sees_imports_inside_functions(tmp_path):
    pkg = tmp_path / "gausstac_maniskill"
    (pkg / "fem").mkdir(parents=True)
    (pkg / "mpm").mkdir()
    for folder in ("agents", "tasks", "assets"):
        (tmp_path / folder).mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "mpm" / "__init__.py").write_text("X = 1\n")
    (pkg / "fem" / "__init__.py").write_text("def f():\n    from ..mpm import X\n    return X\n")
    graph = import_graph.component_graph(tmp_path)
    assert graph["fem"] == {"mpm"} and import_graph.cycles(graph) == []
