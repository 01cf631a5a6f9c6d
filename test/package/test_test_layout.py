"""The suite's own layout (docs/architecture.md): every test module sits in its layer's folder, and no test
module imports another; what several share lives in test/helpers/ (or, for fixtures, test/conftest.py)."""
from __future__ import annotations

import ast
from pathlib import Path

TEST = Path(__file__).resolve().parents[1]
LAYERS = {"core", "io", "live", "bag", "ros", "cli", "package"}


def _imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    modules = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            modules.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            modules.add(("." * node.level) + node.module)
    return modules


def test_every_test_module_sits_in_a_layer_folder():
    misplaced = sorted(str(p.relative_to(TEST)) for p in TEST.rglob("test_*.py") if p.parent.name not in LAYERS
                       or p.parent.parent != TEST)
    assert not misplaced, f"test modules outside test/<layer>/ ({sorted(LAYERS)}): {misplaced}"
    names = [p.name for p in TEST.glob("*/test_*.py")]
    assert len(names) == len(set(names)), "a test module name twice: the layer folders are no packages"
    assert not [p for p in TEST.glob("*/__init__.py") if p.parent.name in LAYERS], "test/io would shadow io"


def test_no_test_module_imports_another():
    offending = {}
    for path in sorted(TEST.rglob("*.py")):
        others = sorted(m for m in _imported_modules(path) if m.lstrip(".").split(".")[-1].startswith("test_")
                        or m.startswith("."))
        if others:
            offending[str(path.relative_to(TEST))] = others
    assert not offending, f"move what is shared to test/helpers/ and import it as helpers.<module>: {offending}"
