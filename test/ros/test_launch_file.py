"""The package's launch file run for real by ROS 2 launch (LaunchService), and what the node it starts
would be: its name, namespace, remapped topics and parameters, as rclpy resolves them from the command
line launch_ros builds.

launch_ros imports composition_interfaces at module level (for composable nodes, which this launch file
does not use); that package has no PyPI wheel, so it is stubbed here, inside these tests only. The
executable launched is a stand-in that records its command line (in a temporary ament prefix, found
through the ament index as `ros2 launch` finds calibration_node); rclpy then applies that command line
to a node, so the names are the ones ROS itself gives.

Needs ROS 2 launch and launch_ros (a ROS install: `apt install ros-jazzy-launch-ros`). They are not on
PyPI (no ros-jazzy-launch wheel; the `launch` distribution there is an unrelated 2017 release) nor in
Debian, so where they are absent these tests skip and say so."""
from __future__ import annotations

import json
import shutil
import sys
import types
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
PACKAGE = "accel_calibration"
LAUNCH_FILE = REPO / "launch" / "calibration.launch.py"
CONFIG_FILE = REPO / "config" / "accel_calibration.yaml"
MISSING = ("ROS 2 launch/launch_ros not installed (not on PyPI nor in Debian; a ROS install has them: "
           "apt install ros-jazzy-launch-ros)")


def _stub_composition_interfaces() -> dict[str, types.ModuleType]:
    """composition_interfaces.srv.LoadNode(.Request/.Response): all launch_ros touches at import time."""
    package = types.ModuleType("composition_interfaces")
    srv = types.ModuleType("composition_interfaces.srv")

    class LoadNode:
        class Request:
            pass

        class Response:
            pass

    srv.LoadNode = LoadNode
    package.srv = srv
    return {"composition_interfaces": package, "composition_interfaces.srv": srv}


@pytest.fixture(scope="module")
def launch_api():
    """(launch, launch_ros) imported with composition_interfaces stubbed; afterwards neither the stub
    nor the launch_ros that saw it stay in sys.modules."""
    pytest.importorskip("launch", reason=MISSING)
    if importlib_find("launch_ros") is None:
        pytest.skip(MISSING)
    stubs = {} if importlib_find("composition_interfaces") is not None else _stub_composition_interfaces()
    before = set(sys.modules)
    sys.modules.update(stubs)
    try:
        import launch
        import launch_ros.actions  # noqa: F401 - imports load_composable_nodes, which needs the stub

        yield launch
    finally:
        for name in set(sys.modules) - before:
            if name.split(".")[0] in ("launch_ros", "composition_interfaces"):
                del sys.modules[name]
        for name in stubs:
            sys.modules.pop(name, None)


def importlib_find(name: str):
    import importlib.util

    try:
        return importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None


RECORDER = """#!{python}
import json, os, sys
with open(os.environ["ACCEL_CALIBRATION_LAUNCHED"], "a") as out:
    out.write(json.dumps(sys.argv[1:]) + "\\n")
"""


@pytest.fixture
def prefix(tmp_path, monkeypatch):
    """A one-package ament prefix: the index entry, the installed config, and a calibration_node that
    records its command line (one JSON line per start) to $ACCEL_CALIBRATION_LAUNCHED."""
    root = tmp_path / "install" / PACKAGE
    (root / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    (root / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE).write_text("")
    (root / "share" / PACKAGE / "config").mkdir(parents=True)
    shutil.copy(CONFIG_FILE, root / "share" / PACKAGE / "config" / CONFIG_FILE.name)
    executable = root / "lib" / PACKAGE / "calibration_node"
    executable.parent.mkdir(parents=True)
    executable.write_text(RECORDER.format(python=sys.executable))
    executable.chmod(0o755)
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(root))
    monkeypatch.setenv("ACCEL_CALIBRATION_LAUNCHED", str(tmp_path / "launched.jsonl"))
    monkeypatch.setenv("ROS_LOG_DIR", str(tmp_path / "log"))
    return root


def _launch(launch, arguments: dict[str, str]) -> int:
    from launch.actions import IncludeLaunchDescription
    from launch.launch_description_sources import PythonLaunchDescriptionSource

    service = launch.LaunchService()
    service.include_launch_description(IncludeLaunchDescription(
        PythonLaunchDescriptionSource(str(LAUNCH_FILE)), launch_arguments=list(arguments.items())))
    return service.run()


def _launched(prefix: Path) -> list[list[str]]:
    lines = (prefix.parents[1] / "launched.jsonl").read_text().splitlines()
    return [json.loads(line) for line in lines]


def _as_ros_resolves(argv: list[str], parameters: list[str]) -> dict:
    """The node's name, its topics and these parameters, as rclpy makes them from this command line."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(args=["calibration_node", *argv], context=context)
    try:
        node = rclpy.create_node("calibration_node", context=context,
                                 automatically_declare_parameters_from_overrides=True)
        try:
            return {
                "name": node.get_fully_qualified_name(),
                "topics": {t: node.resolve_topic_name(t) for t in
                           ("imu/data_raw", "imu/temperature", "imu/data_calibrated", "armed", "diagnostics")},
                "parameters": {p: node.get_parameter(p).value for p in parameters},
            }
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_launch_with_namespace_topics_and_params_file(launch_api, prefix, tmp_path):
    params = tmp_path / "uav1.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {"min_poses": 16, "static": {"window_s": 0.75},
                                                                    "sensor_id": "mpu-0042"}}}))
    assert _launch(launch_api, {"namespace": "uav1", "imu_topic": "/sensors/imu/raw",
                                "temperature_topic": "/sensors/imu/temp", "output_topic": "imu/corrected",
                                "armed_topic": "/fmu/armed", "params_file": str(params)}) == 0
    (argv,) = _launched(prefix)
    assert argv[0] == "--ros-args" and ["--params-file", str(params)] == argv[argv.index("--params-file"):][:2]
    node = _as_ros_resolves(argv, ["min_poses", "static.window_s", "sensor_id"])
    assert node["name"] == "/uav1/accel_calibration"
    assert node["topics"] == {"imu/data_raw": "/sensors/imu/raw", "imu/temperature": "/sensors/imu/temp",
                              "imu/data_calibrated": "/uav1/imu/corrected", "armed": "/fmu/armed",
                              "diagnostics": "/uav1/diagnostics"}
    assert node["parameters"] == {"min_poses": 16, "static.window_s": 0.75, "sensor_id": "mpu-0042"}


def test_launch_defaults_use_the_installed_config(launch_api, prefix):
    """No arguments: the root namespace, the node's own topic names, the installed example parameters."""
    assert _launch(launch_api, {}) == 0
    (argv,) = _launched(prefix)
    installed = prefix / "share" / PACKAGE / "config" / CONFIG_FILE.name
    assert argv[argv.index("--params-file") + 1] == str(installed)
    expected = yaml.safe_load(CONFIG_FILE.read_text())["/**"]["ros__parameters"]
    node = _as_ros_resolves(argv, ["min_poses", "static.window_s"])
    assert node["name"] == "/accel_calibration"
    assert node["topics"] == {"imu/data_raw": "/imu/data_raw", "imu/temperature": "/imu/temperature",
                              "imu/data_calibrated": "/imu/data_calibrated", "armed": "/armed",
                              "diagnostics": "/diagnostics"}
    assert node["parameters"] == {"min_poses": expected["min_poses"],
                                  "static.window_s": expected["static"]["window_s"]}


def test_two_namespaced_instances_are_two_nodes(launch_api, prefix):
    for namespace in ("uav1", "uav2"):
        assert _launch(launch_api, {"namespace": namespace}) == 0
    names = [_as_ros_resolves(argv, [])["name"] for argv in _launched(prefix)]
    assert names == ["/uav1/accel_calibration", "/uav2/accel_calibration"]
