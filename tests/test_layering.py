"""The layering of ../shared/DESIGN.md: imports point downward only; siblings do not import each other."""

from __future__ import annotations

import ast
from pathlib import Path

import dynid

PKG = Path(dynid.__file__).resolve().parent

# rank: a module may import only modules of strictly lower rank (or its own package)
LAYERS = {
    "cli": 9,
    "pipeline": 8,
    "studies": 8,
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
