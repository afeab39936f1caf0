"""The import graph of the project's packages: the layering of ../shared/DESIGN.md and no
import circles (a circle broken by a lazy import inside a function is still a circle).

The graph is read from the source (``ast``), every ``import`` statement wherever it stands,
so it needs no imports of its own and sees the lazy ones too.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("estimator", "sim", "experiments")


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}


def _imports(path: Path, name: str, known: set[str]) -> set[str]:
    """Project modules that ``path`` imports (``from a import b`` counts ``a.b`` when that
    is a module, else ``a``)."""
    out: set[str] = set()
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base
                       for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in known:      # a name inside a module: the module
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    known = set(mods)
    return {name: _imports(path, name, known) for name, path in mods.items()}


def test_the_graph_sees_lazy_imports():
    """The reader finds an import inside a function (what broke the old circles)."""
    g = _graph()
    assert "experiments.techniques" in g["experiments.figures"]
    assert any(m.startswith("estimator") for m in g["experiments.sweep"])


def test_layering_estimator_imports_neither_sim_nor_experiments():
    g = _graph()
    for name, deps in g.items():
        if name.startswith("estimator"):
            bad = sorted(d for d in deps if d.split(".")[0] in ("sim", "experiments"))
            assert not bad, f"{name} imports {bad}"
        if name.startswith("sim"):
            bad = sorted(d for d in deps if d.split(".")[0] == "experiments")
            assert not bad, f"{name} imports {bad}"


def test_no_import_circles():
    """No strongly connected component of the module graph has more than one module
    (Tarjan's algorithm); a package's ``__init__`` importing its own submodules is fine
    and is left out of the graph's edges into the package."""
    g = _graph()
    for name in g:
        g[name] = {d for d in g[name] if not name.startswith(d + ".")}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    circles: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in g[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                circles.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    assert not circles, f"import circles: {circles}"
