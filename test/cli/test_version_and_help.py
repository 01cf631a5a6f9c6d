"""The console scripts as a user first tries them: `accel-calib --version`, `calibration_node --help`."""
from __future__ import annotations

import subprocess

from msg_tools.node_process import installed_command


def test_accel_calib_version_prints_the_version():
    from importlib.metadata import version

    done = subprocess.run([*installed_command("accel-calib"), "--version"], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert done.stdout.strip() == f"accel-calib {version('accel_calibration')}"


def test_calibration_node_help_prints_usage_and_starts_nothing(tmp_path):
    """Finding: `calibration_node --help` started the node (and its worker), which then ran until stopped."""
    for flag in ("--help", "-h"):
        done = subprocess.run([*installed_command("calibration_node"), flag], capture_output=True, text=True,
                              timeout=60, cwd=tmp_path)
        assert done.returncode == 0, done.stderr
        assert done.stdout.startswith("usage: calibration_node"), done.stdout
        for named in ("--ros-args", "calibration_file", "latitude_deg", "docs/node.md"):
            assert named in done.stdout, named
        assert "accel_calibration" not in done.stderr  # no node started: nothing logged
