"""Packaging checks that need no ROS CLI, colcon or `launch`: the launch file, setup.py's installed
files and dependencies, package.xml and the example parameters file agree with each other and with
the code's imports. Files are read with ast / ElementTree / yaml, never executed."""
from __future__ import annotations

import ast
import importlib.util
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from glob import glob
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
PACKAGE = "accel_calibration"
LAUNCH_FILE = REPO / "launch" / "calibration.launch.py"
CONFIG_FILE = REPO / "config" / "accel_calibration.yaml"
CODE_DIRS = [REPO / "accel_calibration", REPO / "msg_tools"]
FIRST_PARTY = {"accel_calibration", "msg_tools"}
PYTHON = sys.executable  # as started (some tests stand another in for it)

# ROS interface packages: their Python modules are the package names themselves.
ROS_INTERFACE = re.compile(r"^[a-z0-9_]+_(msgs|srvs|interfaces)$")
LAUNCH_ARGUMENTS = {
    "namespace": "",
    "params_file": None,  # computed from get_package_share_directory; checked separately
    "imu_topic": "imu/data_raw",
    "temperature_topic": "imu/temperature",
    "output_topic": "imu/data_calibrated",
    "armed_topic": "armed",
}
# Import name -> distribution name in install_requires, where they differ.
DISTRIBUTION = {"yaml": "PyYAML", "backports": "backports.zstd"}
# Modules that are standard library on newer Pythons (optional imports with a fallback).
STDLIB_ELSEWHERE = {"compression"}  # Python 3.14; falls back to backports.zstd


# --- helpers ---------------------------------------------------------------------------------

def _call_name(call: ast.Call) -> str:
    func = call.func
    if isinstance(func, ast.Attribute):
        return func.attr
    if isinstance(func, ast.Name):
        return func.id
    return ""


def _calls(tree: ast.AST, name: str) -> list[ast.Call]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call) and _call_name(n) == name]


def _keywords(call: ast.Call) -> dict[str, ast.expr]:
    return {k.arg: k.value for k in call.keywords if k.arg is not None}


def _module_constants(tree: ast.Module) -> dict[str, object]:
    """Module-level `NAME = <literal>` assignments."""
    out: dict[str, object] = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            try:
                out[node.targets[0].id] = ast.literal_eval(node.value)
            except ValueError:
                pass
    return out


def _evaluate(node: ast.expr, names: dict[str, object]) -> object:
    """A literal, with module constants, `+` and `glob(...)` (kept as ("glob", pattern))."""
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, ast.Name):
        return names[node.id]
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        return _evaluate(node.left, names) + _evaluate(node.right, names)
    if isinstance(node, (ast.List, ast.Tuple)):
        items = [_evaluate(e, names) for e in node.elts]
        return items if isinstance(node, ast.List) else tuple(items)
    if isinstance(node, ast.Call) and _call_name(node) == "glob" and len(node.args) == 1:
        return ("glob", _evaluate(node.args[0], names))
    raise AssertionError(f"setup.py: cannot evaluate {ast.dump(node)}")


def _setup_call() -> tuple[dict[str, ast.expr], dict[str, object]]:
    tree = ast.parse((REPO / "setup.py").read_text(encoding="utf-8"))
    calls = _calls(tree, "setup")
    assert len(calls) == 1, "setup.py: expected one setup(...) call"
    return _keywords(calls[0]), _module_constants(tree)


def _imports(directories: list[Path]) -> dict[str, set[str]]:
    """Top-level absolute imports (including ones inside functions) -> files importing them."""
    found: dict[str, set[str]] = {}
    for directory in directories:
        for path in sorted(directory.rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            for node in ast.walk(tree):
                if isinstance(node, ast.Import):
                    modules = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    modules = [node.module]
                else:
                    continue
                for module in modules:
                    found.setdefault(module.split(".")[0], set()).add(str(path.relative_to(REPO)))
    return found


def _package_xml() -> ET.Element:
    return ET.parse(REPO / "package.xml").getroot()


def _depends(tag: str) -> list[str]:
    return [(e.text or "").strip() for e in _package_xml().findall(tag)]


def _requirement_name(requirement: str) -> str:
    return re.split(r"[\s;<>=!~\[]", requirement.strip(), maxsplit=1)[0]


def _normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


# --- launch file -----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def launch_tree() -> ast.Module:
    return ast.parse(LAUNCH_FILE.read_text(encoding="utf-8"), filename=str(LAUNCH_FILE))


def test_launch_file_defines_generate_launch_description(launch_tree):
    functions = {n.name for n in launch_tree.body if isinstance(n, ast.FunctionDef)}
    assert "generate_launch_description" in functions


def test_launch_file_starts_calibration_node(launch_tree):
    constants = _module_constants(launch_tree)
    nodes = _calls(launch_tree, "Node")
    assert len(nodes) == 1, "expected exactly one launch_ros Node(...)"
    keywords = _keywords(nodes[0])

    def value(key: str) -> object:
        assert key in keywords, f"Node(...) has no {key}="
        return _evaluate(keywords[key], constants)

    assert value("package") == PACKAGE
    assert value("executable") == "calibration_node"
    assert value("name") == "accel_calibration"
    assert value("output") == "screen"
    assert value("emulate_tty") is True
    for key in ("namespace", "parameters", "remappings"):
        assert key in keywords, f"Node(...) has no {key}="
    remapped = [ast.literal_eval(t.elts[0]) for t in keywords["remappings"].elts]
    assert sorted(remapped) == sorted(["imu/data_raw", "imu/temperature", "imu/data_calibrated", "armed"])


def test_launch_file_declares_its_arguments(launch_tree):
    declared: dict[str, ast.Call] = {}
    for call in _calls(launch_tree, "DeclareLaunchArgument"):
        declared[ast.literal_eval(call.args[0])] = call
    assert set(declared) == set(LAUNCH_ARGUMENTS)
    for name, default in LAUNCH_ARGUMENTS.items():
        keywords = _keywords(declared[name])
        assert "default_value" in keywords, f"argument {name} has no default_value"
        if default is not None:
            assert ast.literal_eval(keywords["default_value"]) == default, name
    used = {ast.literal_eval(c.args[0]) for c in _calls(launch_tree, "LaunchConfiguration")}
    assert used == set(LAUNCH_ARGUMENTS), "every declared argument is used, and only those"


def test_launch_default_params_file_is_the_installed_config(launch_tree):
    source = ast.unparse(launch_tree)
    assert _calls(launch_tree, "get_package_share_directory"), "default params_file must come from the share dir"
    assert f'"{CONFIG_FILE.name}"' in source or f"'{CONFIG_FILE.name}'" in source
    assert CONFIG_FILE.exists()


def test_setup_installs_calibration_node_entry_point():
    keywords, _ = _setup_call()
    entry_points = ast.literal_eval(keywords["entry_points"])
    names = {spec.split("=", 1)[0].strip() for spec in entry_points["console_scripts"]}
    assert "calibration_node" in names


# --- setup.py --------------------------------------------------------------------------------

def test_setup_installs_launch_and_config_files():
    keywords, constants = _setup_call()
    data_files = _evaluate(keywords["data_files"], constants)
    installed: dict[str, list[str]] = {}
    for destination, sources in data_files:
        if isinstance(sources, tuple) and sources[0] == "glob":
            files = sorted(glob(str(REPO / sources[1])))
            installed.setdefault(destination, []).append(sources[1])
            assert files, f"setup.py: {sources[1]} matches nothing"
        else:
            installed.setdefault(destination, []).extend(sources)
    share = f"share/{PACKAGE}"
    assert "launch/*.py" in installed.get(f"{share}/launch", [])
    assert "config/*.yaml" in installed.get(f"{share}/config", [])
    assert "package.xml" in installed.get(share, [])
    assert f"resource/{PACKAGE}" in installed.get("share/ament_index/resource_index/packages", [])
    assert (REPO / "resource" / PACKAGE).exists()


def test_install_requires_covers_third_party_imports():
    keywords, _ = _setup_call()
    required = {_normalise(_requirement_name(r)) for r in ast.literal_eval(keywords["install_requires"])}
    ros = set(_depends("exec_depend")) | {"rclpy"}
    missing = {}
    for module, files in _imports(CODE_DIRS).items():
        if module in sys.stdlib_module_names or module in STDLIB_ELSEWHERE or module in FIRST_PARTY:
            continue
        if module in ros or ROS_INTERFACE.match(module):
            continue  # from package.xml (checked below)
        if _normalise(DISTRIBUTION.get(module, module)) not in required:
            missing[module] = sorted(files)
    assert not missing, f"third-party imports missing from setup.py install_requires: {missing}"


# --- package.xml -----------------------------------------------------------------------------

def test_package_xml_names_the_package():
    root = _package_xml()
    assert root.findtext("name") == PACKAGE
    assert root.findtext("export/build_type") == "ament_python"


def test_package_xml_interface_packages_are_importable():
    interfaces = [d for d in _depends("exec_depend") if ROS_INTERFACE.match(d)]
    assert interfaces
    missing = [name for name in interfaces if importlib.util.find_spec(name) is None]
    assert not missing, f"exec_depend interface packages not importable here: {missing}"


def test_package_xml_lists_every_ros_package_the_code_imports():
    exec_depends = set(_depends("exec_depend"))
    imported = {m: f for m, f in _imports(CODE_DIRS).items() if ROS_INTERFACE.match(m) or m == "rclpy"}
    assert {"rclpy", "sensor_msgs"} <= set(imported)
    missing = {m: sorted(f) for m, f in imported.items() if m not in exec_depends}
    assert not missing, f"ROS packages imported but not <exec_depend> in package.xml: {missing}"


def test_package_xml_has_launch_dependencies():
    exec_depends = set(_depends("exec_depend"))
    assert {"launch", "launch_ros", "ament_index_python"} <= exec_depends


# --- parameters file -------------------------------------------------------------------------

def test_config_applies_to_any_namespace_and_node_name():
    document = yaml.safe_load(CONFIG_FILE.read_text(encoding="utf-8"))
    assert isinstance(document, dict)
    assert list(document) == ["/**"]
    parameters = document["/**"]["ros__parameters"]
    assert isinstance(parameters, dict) and parameters


def test_config_lists_every_parameter_at_its_default():
    """The example params file is the parameter table written out: every setting, its default (a
    file that pinned calibration_file would make every node under any namespace write one file)."""
    from accel_calibration.core.settings import PARAMETERS
    from accel_calibration.ros.node import NODE_PARAMETERS

    def flatten(tree, prefix=""):
        for key, value in tree.items():
            if isinstance(value, dict):
                yield from flatten(value, f"{prefix}{key}.")
            else:
                yield f"{prefix}{key}", value

    listed = dict(flatten(yaml.safe_load(CONFIG_FILE.read_text(encoding="utf-8"))["/**"]["ros__parameters"]))
    expected = {p.name: p.default for p in PARAMETERS + NODE_PARAMETERS}
    assert sorted(set(expected) - set(listed)) == [], "parameters missing from the example file"
    assert sorted(set(listed) - set(expected)) == [], "example file sets parameters the node does not have"
    for name, default in expected.items():
        expected_value = pytest.approx(default, nan_ok=True) if isinstance(default, float) else default  # NaN: unset
        assert listed[name] == expected_value, name


# --- console scripts as installed ------------------------------------------------------------

def _fake_script(directory: Path, name: str) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / name
    path.write_text("#!/bin/sh\nexit 0\n")
    path.chmod(0o755)
    return path


@pytest.fixture
def nothing_installed(tmp_path, monkeypatch):
    """No console script beside the interpreter, no ament index, an empty PATH, no override."""
    from msg_tools import node_process

    monkeypatch.setattr(node_process.sys, "executable", str(tmp_path / "bare" / "python3"))
    monkeypatch.delenv("AMENT_PREFIX_PATH", raising=False)
    monkeypatch.delenv(node_process.BIN_ENV, raising=False)
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    return tmp_path


@pytest.mark.parametrize("name", ["accel-calib", "calibration_node"])
def test_console_scripts_are_found_through_the_ament_index(nothing_installed, monkeypatch, name):
    """Where colcon installs them (install/accel_calibration/lib/accel_calibration/) and `ros2 run` finds them."""
    from msg_tools.node_process import installed_command

    prefix = nothing_installed / "install" / PACKAGE
    _fake_script(prefix / "share" / "ament_index" / "resource_index" / "packages", PACKAGE)
    script = _fake_script(prefix / "lib" / PACKAGE, name)
    monkeypatch.setenv("AMENT_PREFIX_PATH", f"{nothing_installed / 'elsewhere'}:{prefix}")
    assert installed_command(name) == [str(script)]


def test_console_scripts_beside_the_interpreter_come_first(nothing_installed, monkeypatch):
    """A virtualenv's own install (make venv) wins over a sourced workspace's."""
    from msg_tools import node_process

    prefix = nothing_installed / "install" / PACKAGE
    _fake_script(prefix / "share" / "ament_index" / "resource_index" / "packages", PACKAGE)
    _fake_script(prefix / "lib" / PACKAGE, "accel-calib")
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    beside = _fake_script(nothing_installed / "venv" / "bin", "accel-calib")
    monkeypatch.setattr(node_process.sys, "executable", str(beside.parent / "python3"))
    assert node_process.installed_command("accel-calib") == [str(beside)]


def test_console_scripts_on_path_and_the_override(nothing_installed, monkeypatch):
    from msg_tools.node_process import BIN_ENV, installed_command

    on_path = _fake_script(nothing_installed / "usr-bin", "calibration_node")
    monkeypatch.setenv("PATH", str(on_path.parent))
    assert installed_command("calibration_node") == [str(on_path)]
    chosen = _fake_script(nothing_installed / "chosen", "calibration_node")
    monkeypatch.setenv(BIN_ENV, str(chosen.parent))
    assert installed_command("calibration_node") == [str(chosen)]
    monkeypatch.setenv(BIN_ENV, str(nothing_installed / "nowhere"))
    with pytest.raises(FileNotFoundError, match=BIN_ENV):
        installed_command("calibration_node")
    with pytest.raises(ValueError, match="not a console script"):
        installed_command("calibration-node")


def test_console_scripts_fall_back_to_python_m_and_that_runs(nothing_installed):
    from msg_tools.node_process import installed_command

    command = installed_command("accel-calib")
    assert command[1:] == ["-m", "accel_calibration.cli.main"]
    command[0] = PYTHON  # the fixture's stand-in interpreter does not exist
    run = subprocess.run([*command, "--help"], capture_output=True, text=True, timeout=60, cwd=REPO)
    assert run.returncode == 0 and "usage: accel-calib" in run.stdout, run.stderr
    assert installed_command("calibration_node")[1:] == ["-m", "accel_calibration.ros.node"]


# --- rosdep keys -----------------------------------------------------------------------------

# Import -> its rosdep key, for every third-party import that has one (ros/rosdistro rosdep/python.yaml,
# 2026-08): rosdep installs these from package.xml.
ROSDEP_KEYS = {"numpy": "python3-numpy", "scipy": "python3-scipy", "yaml": "python3-yaml",
               "matplotlib": "python3-matplotlib", "tqdm": "python3-tqdm", "rosbags": "python3-rosbags-pip"}
TEST_ROSDEP_KEYS = {"pytest": "python3-pytest", "hypothesis": "python3-hypothesis"}
# No key (or, for SQLAlchemy, only one too old: Debian's and Ubuntu's 1.4; psycopg's is psycopg 2): a
# colcon user installs these with `pip install -r requirements-ros.txt` (README, "In a ROS 2 workspace").
NO_ROSDEP_KEY = {"lz4", "backports", "pyulog", "pymavlink", "regex", "pyarrow", "dask", "distributed", "sqlalchemy",
                 "psycopg"}
# Of those, the ones rosbags requires (pip install rosbags, which python3-rosbags-pip runs, brings them).
WITH_ROSBAGS = {"lz4", "backports"}


def _third_party(directories: list[Path]) -> set[str]:
    ros = set(_depends("exec_depend")) | {"rclpy"}
    return {m for m in _imports(directories) if m not in sys.stdlib_module_names and m not in STDLIB_ELSEWHERE
            and m not in FIRST_PARTY and m not in ros and not ROS_INTERFACE.match(m)}


def test_package_xml_declares_every_dependency_that_has_a_rosdep_key():
    imported = _third_party(CODE_DIRS)
    unknown = sorted(imported - set(ROSDEP_KEYS) - NO_ROSDEP_KEY)
    assert not unknown, f"new third-party imports: look up their rosdep keys and add them here: {unknown}"
    declared = set(_depends("exec_depend"))
    missing = sorted(ROSDEP_KEYS[m] for m in imported & set(ROSDEP_KEYS) if ROSDEP_KEYS[m] not in declared)
    assert not missing, f"<exec_depend> missing from package.xml: {missing}"
    tests = _third_party([REPO / "test"]) & set(TEST_ROSDEP_KEYS)
    missing = sorted(TEST_ROSDEP_KEYS[m] for m in tests if TEST_ROSDEP_KEYS[m] not in set(_depends("test_depend")))
    assert not missing, f"<test_depend> missing from package.xml: {missing}"
    assert "python3-setuptools" in _depends("build_depend")


def test_dependencies_without_a_rosdep_key_are_in_requirements_and_the_readme():
    """requirements-ros.txt (what a ROS workspace pip-installs) holds exactly what rosdep cannot install,
    and requirements.txt includes it (it also brings PyPI's ROS wheels, unwanted in a ROS install)."""
    from importlib.metadata import requires

    def names(path: Path) -> list[str]:
        return [_normalise(_requirement_name(line)) for line in path.read_text(encoding="utf-8").splitlines()
                if line.strip() and not line.startswith(("#", "-"))]

    ros_requirements = names(REPO / "requirements-ros.txt")
    assert "-r requirements-ros.txt" in (REPO / "requirements.txt").read_text(encoding="utf-8").splitlines()
    assert not set(ros_requirements) & set(names(REPO / "requirements.txt")), "pinned twice"
    with_rosbags = {_normalise(_requirement_name(r)) for r in requires("rosbags") or [] if "extra ==" not in r}
    expected = set()
    for module in NO_ROSDEP_KEY:
        distribution = _normalise(DISTRIBUTION.get(module, module))
        if module in WITH_ROSBAGS:
            assert distribution in with_rosbags, f"{module}: rosbags no longer requires it; pin it"
        else:
            expected.add(distribution)
    assert set(ros_requirements) == expected
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    assert "## In a ROS 2 workspace" in readme
    section = readme.split("## In a ROS 2 workspace", 1)[1].split("\n## ", 1)[0]
    for command in ("rosdep install", "pip install -r", "requirements-ros.txt", "colcon build", "colcon test",
                    "ros2 run accel_calibration calibration_node", "ros2 launch accel_calibration"):
        assert command in section, command


# --- colcon build --------------------------------------------------------------------------------

BUILD_INPUTS = ["accel_calibration", "msg_tools", "launch", "config", "resource", "package.xml", "setup.py",
                "setup.cfg"]


@pytest.mark.parametrize("symlink", [False, True], ids=["plain", "symlink-install"])
def test_colcon_build_installs_what_ros2_run_and_launch_find(tmp_path, monkeypatch, symlink):
    """`colcon build` (plain and --symlink-install) of this package in a fresh workspace; the console
    scripts run from where the ament index says (as ros2 run finds them). Needs colcon (make colcon-test
    installs it: requirements-colcon.txt)."""
    colcon = shutil.which("colcon") or (str(Path(PYTHON).parent / "colcon")
                                        if (Path(PYTHON).parent / "colcon").exists() else None)
    if colcon is None:
        pytest.skip("colcon not installed (make colcon-test installs it into .venv-colcon)")
    source = tmp_path / "ws" / "src" / PACKAGE
    source.mkdir(parents=True)
    for name in BUILD_INPUTS:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, source / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy(REPO / name, source / name)
    build = subprocess.run([colcon, "build", *(["--symlink-install"] if symlink else [])], cwd=tmp_path / "ws",
                           capture_output=True, text=True, timeout=300)
    assert build.returncode == 0, build.stdout + build.stderr
    prefix = tmp_path / "ws" / "install" / PACKAGE
    share = prefix / "share" / PACKAGE
    for installed in ("package.xml", "launch/calibration.launch.py", "config/accel_calibration.yaml"):
        assert (share / installed).is_file(), installed
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE).is_file()

    from msg_tools import node_process

    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    monkeypatch.setattr(node_process.sys, "executable", str(tmp_path / "bare" / "python3"))
    monkeypatch.delenv(node_process.BIN_ENV, raising=False)
    accel_calib = node_process.installed_command("accel-calib")
    node = node_process.installed_command("calibration_node")
    assert accel_calib == [str(prefix / "lib" / PACKAGE / "accel-calib")]
    assert node == [str(prefix / "lib" / PACKAGE / "calibration_node")]
    monkeypatch.undo()
    # As a user runs them: the workspace's setup sourced, from elsewhere than this checkout.
    setup = tmp_path / "ws" / "install" / "setup.bash"
    assert setup.is_file()

    def sourced(*command: str) -> subprocess.CompletedProcess:
        return subprocess.run(["bash", "-c", 'source "$0" && exec "$@"', str(setup), *command],
                              capture_output=True, text=True, timeout=60, cwd=tmp_path)

    run = sourced(*accel_calib, "--help")
    assert run.returncode == 0 and "usage: accel-calib" in run.stdout, run.stderr
    run = sourced(*node, "--ros-args", "-p", "static.window_s:=0.0")
    output = (run.stdout + run.stderr).strip()
    assert run.returncode == 2 and "static.window_s must be within" in output, output
    run = sourced(PYTHON, "-c", "import accel_calibration; print(accel_calibration.__file__)")
    assert run.returncode == 0 and run.stdout.startswith(str(tmp_path / "ws")), run.stdout + run.stderr
