"""The core must import and fit with no ROS on the path (habit 1 of STYLE.md)."""
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "accel_calibration"
CORE_MODULES = [f"accel_calibration.core.{p.stem}" for p in sorted((PACKAGE / "core").glob("*.py"))
                if p.stem != "__init__"] + [
    "accel_calibration",
    "accel_calibration.core.fit",
    "accel_calibration.core.models",
    "accel_calibration.core.gauss_newton",
    "accel_calibration.core.coverage",
    "accel_calibration.core.calibration",
    "accel_calibration.io.calibration_file",
    "accel_calibration.io.pose_table",
    "accel_calibration.cli.main",
    "accel_calibration.core.stream.detector",
]

PROBE = f"""
import importlib.abc, sys
class NoRos(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('rclpy', 'sensor_msgs', 'std_srvs', 'diagnostic_msgs', 'builtin_interfaces',
                                  'rosbags', 'dask', 'distributed', 'sqlalchemy'):
            # ROS from the core; Dask and SQLAlchemy only when a fleet/history command runs
            raise ImportError('ROS import from the core: ' + name)
sys.meta_path.insert(0, NoRos())
import importlib
for module in {CORE_MODULES!r}:
    importlib.import_module(module)
import numpy as np
from accel_calibration import fit
d = np.vstack([np.eye(3), -np.eye(3), [[1, 1, 0], [0, 1, 1], [1, 0, 1], [-1, 1, 0], [0, -1, 1], [1, 0, -1]]])
d = d / np.linalg.norm(d, axis=1)[:, None]
assert fit(9.80665 * d + 0.1).success
print('ok')
"""


def test_core_imports_no_ros():
    run = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, check=False)
    assert run.returncode == 0 and run.stdout.strip() == "ok", run.stderr


# The layers' import direction and the absence of import circles: test_layers.py.
