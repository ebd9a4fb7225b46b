"""The layering of ../shared/DESIGN.md: imports point downward only; siblings do not import each other;
imports form no cycle (inside a layer too); a package attribute never hides a submodule."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import dynid

PKG = Path(dynid.__file__).resolve().parent

# rank: a module may import only modules of strictly lower rank (or its own package); modules
# inside one package (model/_xml.py, model/mechanism_files.py, ...) have no rank: there the
# check is that they form no cycle (test_imports_form_no_cycle)
LAYERS = {
    "cli": 10,
    "studies": 9,  # a study composes pipeline runs (simulate, identify) on the papers' set-ups
    "fleet": 9,  # many robots x many logs: pipeline runs on Dask and the fleet statistics
    "pipeline": 8,
    "config": 7,
    "report": 6,
    "io": 6,
    "excitation": 5,
    "estimation": 5,
    "simulation": 5,
    "learning": 5,
    "model": 4,
    "signals": 3,
    "trajectories": 3,
    "stats": 3,
    "dataset": 2,
    "_typing": 1,
    "_files": 1,
    "errors": 1,
    "tolerances": 2,  # imports errors
}


def _top(module: str) -> str:
    return module.split(".")[1] if module.startswith("dynid.") else ""


def _imports(path: Path) -> list[tuple[str, int]]:
    tree = ast.parse(path.read_text(), filename=str(path))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names if a.name.startswith("dynid.")]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0 and node.module.startswith("dynid"):
            if node.module == "dynid":
                out += [(f"dynid.{a.name}", node.lineno) for a in node.names if a.name in LAYERS]
            else:
                out.append((node.module, node.lineno))
    return out


def test_every_module_belongs_to_a_layer():
    for path in PKG.rglob("*.py"):
        rel = path.relative_to(PKG)
        top = rel.parts[0].removesuffix(".py")
        assert top in LAYERS or top == "__init__", f"{rel} is in no layer of DESIGN.md"


def test_imports_point_downward():
    violations = []
    for path in PKG.rglob("*.py"):
        rel = path.relative_to(PKG)
        me = rel.parts[0].removesuffix(".py")
        if me == "__init__":
            continue
        for target, line in _imports(path):
            other = _top(target)
            if not other or other == me:
                continue
            if other not in LAYERS:
                violations.append(f"{rel}:{line} imports unknown dynid.{other}")
            elif LAYERS[other] >= LAYERS[me]:
                violations.append(f"{rel}:{line} ({me}, layer {LAYERS[me]}) imports {target} (layer {LAYERS[other]})")
    assert not violations, "layering violations:\n" + "\n".join(violations)


def test_the_check_sees_a_violation(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("from dynid.pipeline import identify\nimport dynid.cli\n")
    found = [t for t, _ in _imports(bad)]
    assert found == ["dynid.pipeline", "dynid.cli"]


def test_import_dynid_is_light():
    import subprocess
    import sys

    code = "import sys, dynid; heavy = [m for m in ('pinocchio', 'scipy', 'matplotlib', 'pandas', 'torch') if m in sys.modules]; print(heavy)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]"


# ---------------------------------------------------------------------- import cycles


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _statements(tree: ast.AST) -> Iterator[ast.AST]:
    """Every node of ``tree``, function bodies and ``if TYPE_CHECKING:`` blocks included."""
    return ast.walk(tree)


def import_graph(root: Path) -> dict[str, set[str]]:
    """The module import graph of the package in ``root``: module name -> modules it imports.

    Counted: every ``import a.b``, ``from a.b import c`` and relative import of the package,
    anywhere in a file, imports inside functions included (a lazy import still closes a
    cycle), and imports under ``if TYPE_CHECKING:`` (never executed, but a reader still follows
    them: issue 38 asks for no cycle, typing-only included). ``from pkg import name`` is an edge to
    ``pkg.name`` when that is a module, else to ``pkg`` itself. Not counted: the implicit import of
    parent packages, and ``importlib.import_module`` calls.
    """
    files = {_module_name(p, root): p for p in sorted(root.rglob("*.py"))}
    graph: dict[str, set[str]] = {name: set() for name in files}
    for me, path in files.items():
        package = me if path.name == "__init__.py" else me.rpartition(".")[0]
        for node in _statements(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                    module = f"{base}.{node.module}" if node.module else base
                else:
                    module = node.module or ""
                targets = [f"{module}.{a.name}" if f"{module}.{a.name}" in files else module for a in node.names]
            else:
                continue
            graph[me].update(t for t in targets if t in files and t != me)
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def _cycle_text(graph: dict[str, set[str]], component: list[str]) -> str:
    members = set(component)
    edges = [f"{a} -> {b}" for a in component for b in sorted(graph[a] & members)]
    return "  " + " | ".join(component) + "\n" + "\n".join(f"    {e}" for e in edges)


def test_imports_form_no_cycle():
    """No strongly connected component of more than one module in :func:`import_graph` (which
    counts lazy imports inside functions and those under ``if TYPE_CHECKING:``); a module
    importing itself is not a cycle."""
    graph = import_graph(PKG)
    cycles = import_cycles(graph)
    assert not cycles, "import cycles:\n" + "\n".join(_cycle_text(graph, c) for c in cycles)


def test_the_check_sees_a_cycle(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from pkg.b import g\n\ndef f():\n    return g()\n")
    (pkg / "b.py").write_text("def g():\n    from pkg import a\n    return a\n")
    # an edge in, a self-edge, and an import for type checkers only (an edge too): no cycle through c
    (pkg / "c.py").write_text(
        "from typing import TYPE_CHECKING\nfrom . import a\nimport pkg.c\n\nif TYPE_CHECKING:\n    from pkg.b import g\n"
    )
    # a typing-only import back closes a cycle
    (pkg / "d.py").write_text("from pkg.e import h\n")
    (pkg / "e.py").write_text("from typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n    from pkg.d import k\n\ndef h():\n    pass\n")
    graph = import_graph(pkg)
    assert graph == {"pkg": set(), "pkg.a": {"pkg.b"}, "pkg.b": {"pkg.a"}, "pkg.c": {"pkg.a", "pkg.b"},
                     "pkg.d": {"pkg.e"}, "pkg.e": {"pkg.d"}}
    assert import_cycles(graph) == [["pkg.a", "pkg.b"], ["pkg.d", "pkg.e"]]


def test_no_package_attribute_shadows_a_submodule():
    """``pkg.name`` is the module ``pkg/name.py`` if that exists, never a function re-exported
    under the module's name (then ``import pkg.name`` and ``pkg.name`` differ)."""
    import importlib
    import pkgutil

    shadowed = []
    for init in sorted(PKG.rglob("__init__.py")):
        name = _module_name(init, PKG)
        package = importlib.import_module(name)
        for sub in pkgutil.iter_modules([str(init.parent)]):
            full = f"{name}.{sub.name}"
            value = getattr(package, sub.name, None)
            if value is not None and value is not importlib.import_module(full):
                shadowed.append(f"{name}.{sub.name} is a module and also {value!r}")
    assert not shadowed, "package attributes that shadow a submodule:\n" + "\n".join(shadowed)
