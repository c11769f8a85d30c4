"""The package's import graph, read from the source with ``ast`` (nothing is imported).

Nodes are components: a subpackage (``fem``, ``mpm``, ``splat``, ...) or a top-level module
(``cosim``, ``config``, ...). ``agents/``, ``tasks/`` and ``assets/`` count as the package's
``agents``, ``tasks`` and ``assets``. Every import counts, including those inside functions.

    python scripts/import_graph.py [--root .] [--png docs/import_graph.png]

prints the edges, the cycles between components and the edges that go against the layering
(``LAYERS``), and draws the graph with the components in rows by layer (edges against the
layering or inside a cycle in red).
"""
from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

PACKAGE = "gausstac_maniskill"
MAPPED = {"agents": "agents", "tasks": "tasks", "assets": "assets"}  # top-level folder -> component

#: Layer of each component, lowest first: a component may import only from its own layer or below.
LAYERS: dict[str, int] = {
    "errors": 0, "environment": 0, "config": 0, "backend": 0, "cache": 0, "cpu_pinning": 0,
    "kernel_launch": 0, "transforms": 0, "assets": 0, "_registry": 0, "owner": 0,
    "geometry": 1, "urdf": 1, "reference": 1,
    "fem": 2, "mpm": 2, "tactile": 2, "optical": 2, "splat": 2, "pose": 2, "pads": 2,
    "cosim": 3, "batch": 3, "render": 3,
    "sensors": 4, "obs_wrappers": 4, "agents": 4, "tasks": 4, "experts": 4,
    "tactile_env": 4, "task_checks": 4, "scene_objects": 4, "physx": 4, "stock_tasks": 4,
    "collect": 5, "replay": 5, "add_tactile": 5, "demo": 5, "bench": 5, "cli": 6,
    "__init__": 0,  # the package: register() and lazy submodules, importing only _registry
}


def source_files(root: Path) -> dict[str, Path]:
    """Map dotted module names (``gausstac_maniskill.fem.contact``) to their files."""
    files = {}
    for path in sorted((root / PACKAGE).rglob("*.py")):
        rel = path.relative_to(root).with_suffix("")
        files[".".join(rel.parts)] = path
    for folder in MAPPED:
        for path in sorted((root / folder).rglob("*.py")):
            rel = path.relative_to(root).with_suffix("")
            files[".".join((PACKAGE, *rel.parts))] = path
    return {name.removesuffix(".__init__"): path for name, path in files.items()}


def component(module: str) -> str:
    """``gausstac_maniskill.fem.contact`` -> ``fem``; the package itself -> ``__init__``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def imported_modules(name: str, path: Path, is_package: bool) -> set[str]:
    """The package modules that one file imports (absolute names), at any depth of the file."""
    tree = ast.parse(path.read_text(), filename=str(path))
    here = name.split(".") if is_package else name.split(".")[:-1]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] == PACKAGE)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = here[: len(here) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != PACKAGE:
                continue
            out.update(f"{target}.{a.name}" for a in node.names)  # a module, or a name in target
    return out


def component_graph(root: Path) -> dict[str, set[str]]:
    """Component -> the components it imports (self-edges left out)."""
    files = source_files(root)
    graph: dict[str, set[str]] = {component(m): set() for m in files}
    for name, path in files.items():
        for target in imported_modules(name, path, path.name == "__init__.py"):
            while target not in files and "." in target:
                target = target.rsplit(".", 1)[0]  # "from .mpm import Sphere" names a symbol
            if target in files and component(target) != component(name):
                graph[component(name)].add(component(target))
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one member (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def against_layers(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """Edges from a component to one in a higher layer (unknown components rank as 3)."""
    rank = lambda c: LAYERS.get(c, 3)  # noqa: E731
    return sorted((a, b) for a, deps in graph.items() for b in deps if rank(b) > rank(a))


def draw(graph: dict[str, set[str]], png: Path, title: str) -> None:
    """Components in rows by layer (lowest at the bottom); edges against the layering or in a cycle in red."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows: dict[int, list[str]] = {}
    for c in sorted(graph):
        rows.setdefault(LAYERS.get(c, 3), []).append(c)
    pos = {}
    for layer, names in rows.items():
        for i, c in enumerate(names):
            pos[c] = ((i + 0.5) / len(names), layer)
    in_cycle = {c: i for i, group in enumerate(cycles(graph)) for c in group}
    bad = set(against_layers(graph)) | {(a, b) for a, deps in graph.items() for b in deps
                                        if a in in_cycle and in_cycle[a] == in_cycle.get(b)}
    fig, ax = plt.subplots(figsize=(14, 8))
    for a, deps in graph.items():
        for b in deps:
            red = (a, b) in bad
            bend = 0.25 if pos[a][1] == pos[b][1] else 0.0  # same-row edges arc above the row
            ax.annotate("", xy=pos[b], xytext=pos[a],
                        arrowprops=dict(arrowstyle="->", lw=1.6 if red else 0.6, alpha=0.9 if red else 0.35,
                                        color="crimson" if red else "gray", shrinkA=12, shrinkB=12,
                                        connectionstyle=f"arc3,rad={bend}"))
    for c, (x, y) in pos.items():
        ax.text(x, y, c, ha="center", va="center", fontsize=9,
                bbox=dict(boxstyle="round", fc="lightyellow" if c in ("fem", "mpm") else "white", ec="black"))
    ax.set_xlim(-0.05, 1.05)
    ax.set_ylim(-0.6, max(rows) + 0.6)
    ax.set_yticks(sorted(rows))
    ax.set_ylabel("layer (imports point down)")
    ax.set_xticks([])
    n_cyc = len(cycles(graph))
    ax.set_title(f"{title}: {sum(map(len, graph.values()))} edges between {len(graph)} components, "
                 f"{len(against_layers(graph))} against the layering, {n_cyc} cycles (red)")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1])
    ap.add_argument("--png", type=Path, default=None, help="draw the graph to this file")
    ap.add_argument("--title", default="import graph")
    args = ap.parse_args(argv)
    graph = component_graph(args.root)
    for a in sorted(graph):
        print(f"{a:>14} -> {', '.join(sorted(graph[a])) or '-'}")
    print("cycles:", cycles(graph) or "none")
    print("against the layering:", against_layers(graph) or "none")
    if args.png:
        draw(graph, args.png, args.title)
        print("wrote", args.png)
    return 0


if __name__ == "__main__":
    sys.exit(main())
