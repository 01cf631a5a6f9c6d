"""Run calibration_node as its own process, as a user does (console script + --ros-args), and find the
package's console scripts wherever they were installed."""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

PACKAGE = "accel_calibration"
# Console script -> the module its entry point runs (setup.py), for `python -m` where none is installed.
CONSOLE_SCRIPTS = {"accel-calib": "accel_calibration.cli.main", "calibration_node": "accel_calibration.ros.node"}
# A directory holding the console scripts to test, overriding the search (e.g. another install's bin/).
BIN_ENV = "ACCEL_CALIBRATION_BIN"


def _ament_index_executable(name: str) -> Path | None:
    """Where `ros2 run accel_calibration NAME` finds it: <prefix>/lib/accel_calibration/NAME, the prefix
    from the ament index (AMENT_PREFIX_PATH: a sourced colcon workspace, and what `colcon test` sets)."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_prefix
    except ImportError:
        return None
    try:
        prefix = get_package_prefix(PACKAGE)
    except (PackageNotFoundError, OSError, ValueError):  # not in the index, or no AMENT_PREFIX_PATH at all
        return None
    path = Path(prefix) / "lib" / PACKAGE / name
    return path if path.is_file() and os.access(path, os.X_OK) else None


def installed_command(name: str) -> list[str]:
    """The command line that runs console script `name` ("accel-calib", "calibration_node") as installed:
    $ACCEL_CALIBRATION_BIN/NAME if set; beside sys.executable (a virtualenv's pip install, `make venv`);
    through the ament index (colcon's install/accel_calibration/lib/accel_calibration/); on PATH; else
    `python -m` its module (a source checkout on PYTHONPATH with nothing installed)."""
    if name not in CONSOLE_SCRIPTS:
        raise ValueError(f"not a console script of {PACKAGE}: {name!r}")
    override = os.environ.get(BIN_ENV)
    if override:
        path = Path(override) / name
        if not path.is_file():
            raise FileNotFoundError(f"{BIN_ENV}={override}: no {name} there")
        return [str(path)]
    beside = Path(sys.executable).parent / name
    if beside.is_file() and os.access(beside, os.X_OK):
        return [str(beside)]
    indexed = _ament_index_executable(name)
    if indexed is not None:
        return [str(indexed)]
    on_path = shutil.which(name)
    if on_path is not None:
        return [on_path]
    return [sys.executable, "-m", CONSOLE_SCRIPTS[name]]


class NodeProcess:
    """calibration_node as a user runs it (console script), with --ros-args parameters.

    `calibration_file` None leaves the node's per-node default; `ros_args` are added verbatim
    (e.g. ["-r", "__ns:=/uav1", "--params-file", path]); `env` overrides environment variables."""

    def __init__(self, calibration_file: Path | None, *params: str, log_path: Path | None = None,
                 ros_args: list[str] | None = None, env: dict[str, str] | None = None):
        args = [*installed_command("calibration_node"), "--ros-args"]
        if calibration_file is not None:
            args += ["-p", f"calibration_file:={calibration_file}"]
        for p in params:
            args += ["-p", p]
        args += list(ros_args or [])
        if log_path is None:
            if calibration_file is None:
                raise ValueError("give log_path when calibration_file is None")
            log_path = calibration_file.with_suffix(".node.log")
        self.log_path = log_path
        self._log = open(self.log_path, "w")
        self.process = subprocess.Popen(args, stdout=self._log, stderr=subprocess.STDOUT,
                                        env={**os.environ, **(env or {})})

    def log(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()

    def stop(self, timeout: float = 15.0) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self._log.close()
        return self.process.returncode
