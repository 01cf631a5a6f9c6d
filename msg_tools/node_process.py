"""Run calibration_node as its own process, as a user does (console script + --ros-args)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path


class NodeProcess:
    """calibration_node as a user runs it (console script), with --ros-args parameters.

    `calibration_file` None leaves the node's per-node default; `ros_args` are added verbatim
    (e.g. ["-r", "__ns:=/uav1", "--params-file", path]); `env` overrides environment variables."""

    def __init__(self, calibration_file: Path | None, *params: str, log_path: Path | None = None,
                 ros_args: list[str] | None = None, env: dict[str, str] | None = None):
        args = [str(Path(sys.executable).parent / "calibration_node"), "--ros-args"]
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
