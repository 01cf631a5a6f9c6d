"""The package's import graph, read from the source (no import runs): no module imports another that
imports it back, directly or around a circle, whether at the top or inside a function (a lazy import
hides a circle, it does not remove it); and the layers point one way, core <- io <- live <- ros, and
core <- io <- bag, cli.
Imports under `if TYPE_CHECKING:` are for annotations only and are left out of the circles."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "accel_calibration"

# What each layer may import (docs/architecture.md, "Layers"): core imports nothing of ours; io the core;
# live (the node's work without ROS) io and the core; ros live, io and the core; bag and cli io and the core,
# cli also bag (replay). ros does not read recordings; nothing imports ros.
ALLOWED = {"core": {"core"}, "io": {"core", "io"}, "live": {"core", "io", "live"}, "bag": {"core", "io", "bag"},
           "ros": {"core", "io", "live", "ros"}, "cli": {"core", "io", "bag", "cli"}}

# Circles still there, each in files being rewritten elsewhere. When one goes, remove it here: the test
# says so. (None left: the stream side's detector no longer reaches into its batch module and back.)
KNOWN_CYCLES: set[frozenset[str]] = set()


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def imports_of(name: str, *, annotations: bool) -> set[str]:
    """The package's modules `name` imports anywhere in its body (functions included); with
    `annotations`, also those under `if TYPE_CHECKING:`."""
    path = MODULES[name]
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node) and not annotations:
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            for alias in node.names:  # `from . import replay` imports the submodule
                found.add(f"{module}.{alias.name}" if f"{module}.{alias.name}" in MODULES else module)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(ast.parse(path.read_text(encoding="utf-8")))
    return {m for m in found if m in MODULES and m not in (name, "accel_calibration")}


def import_cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components of more than one module (Tarjan), each a set of modules
    that reach one another through imports."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[set[str]] = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.add(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(component)

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return cycles


def test_the_cycle_finder_finds_a_circle_and_only_circles():
    assert import_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]
    assert import_cycles({"a": {"b"}, "b": set(), "c": {"a", "b"}}) == []


def test_a_lazy_import_counts_and_an_annotation_only_one_does_not():
    # cli/fleet.py imports io.history under TYPE_CHECKING and inside functions
    assert "accel_calibration.io.history" in imports_of("accel_calibration.cli.fleet", annotations=False)
    assert "accel_calibration.bag.replay" in imports_of("accel_calibration.cli.options", annotations=False)


def test_no_module_imports_itself_around_a_circle():
    graph = {name: imports_of(name, annotations=False) for name in MODULES}
    found = {frozenset(cycle) for cycle in import_cycles(graph)}
    new = found - KNOWN_CYCLES
    assert not new, "import circles: " + "; ".join(
        " <-> ".join(sorted(m.removeprefix("accel_calibration.") for m in cycle)) for cycle in new)
    gone = KNOWN_CYCLES - found
    assert not gone, f"no longer a circle, remove from KNOWN_CYCLES: {[sorted(c) for c in gone]}"


@pytest.mark.parametrize("layer", sorted(ALLOWED))
def test_imports_point_from_the_outer_layers_to_the_core(layer):
    wrong = {}
    for name in MODULES:
        if name.split(".")[1:2] != [layer]:
            continue
        layers = {m.split(".")[1] for m in imports_of(name, annotations=True) if m.count(".") >= 1}
        if layers - ALLOWED[layer]:
            wrong[name] = sorted(layers - ALLOWED[layer])
    assert not wrong, f"{layer}/ imports layers it must not: {wrong}"


def test_msg_tools_import_nothing_of_the_package():
    for path in sorted((ROOT / "msg_tools").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0
                     else [a.name for a in node.names] if isinstance(node, ast.Import) else [])
            assert not any(n.split(".")[0] == "accel_calibration" for n in names), f"{path.name}: {names}"


def test_no_circle_even_through_annotations():
    """The stream side (core/stream/) never names the session, not even in an annotation: the feed takes
    the stream side, the session composes it."""
    graph = {name: imports_of(name, annotations=True) for name in MODULES}
    assert not import_cycles(graph), "import circles through annotations: " + "; ".join(
        " <-> ".join(sorted(m.removeprefix("accel_calibration.") for m in cycle)) for cycle in import_cycles(graph))


def test_the_node_is_wiring_only_of_at_most_250_lines():
    """docs/architecture.md: ros/node.py wires topics, services and timers to the live layer; what it
    computes lives in live/ (and the Imu path in ros/imu_path.py), so the file stays short."""
    lines = len((PACKAGE / "ros" / "node.py").read_text(encoding="utf-8").splitlines())
    assert lines <= 250, f"ros/node.py has {lines} lines: move what it computes to live/ or a module of ros/"
    assert "accel_calibration.live.per_message" in imports_of("accel_calibration.ros.node", annotations=False)


# The core modules that compose the parts and so read Settings whole (docs/maintaining.md, "A parameter");
# every other core module takes its own option object.
READ_SETTINGS_WHOLE = {"core.settings", "core.session", "core.stream.stream_side", "core.stream.screening",
                       "core.warmup"}


def test_only_the_composing_core_modules_read_settings_whole():
    readers = {name.removeprefix("accel_calibration.") for name in MODULES if name.startswith("accel_calibration.core")
               and "accel_calibration.core.settings" in imports_of(name, annotations=True)}
    assert readers | {"core.settings"} == READ_SETTINGS_WHOLE, \
        f"core modules reading Settings whole: {sorted(readers)}; give a new one its own option object"


def test_every_error_of_the_package_is_an_accel_calibration_error():
    """docs/maintaining.md, "Errors": the CLI prints any AccelCalibrationError as one line, so every error
    type the package raises to a user derives from it (a module's private one, caught inside it, aside)."""
    import importlib

    from accel_calibration.core.errors import AccelCalibrationError

    outside = []
    for name, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef) and node.name.endswith("Error") and not node.name.startswith("_"):
                try:
                    module = importlib.import_module(name)
                except ImportError:  # a module needing an absent optional package: read its bases as text
                    bases = {ast.unparse(base) for base in node.bases}
                    if not bases & {"AccelCalibrationError", "CalibrationError", "BagError"}:
                        outside.append(f"{name}.{node.name}")
                    continue
                if not issubclass(getattr(module, node.name), AccelCalibrationError):
                    outside.append(f"{name}.{node.name}")
    assert not outside, f"errors outside AccelCalibrationError: {outside}"
