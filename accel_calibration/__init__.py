"""Online MEMS accelerometer calibration.

The core -- models, Gauss-Newton fit, static detector, calibration files -- imports no ROS; the
node (`calibration_node`), bag replay and the CLI are adapters over it.
Convention everywhere: SI units and a_true = M (a_raw - b).
"""
from .core.calibration import MG, STANDARD_GRAVITY, Calibration, Quality
from .core.errors import CalibrationError
from .core.fit import FitResult, Sigma, fit
from .core.models import MODELS
from .core.pose import Pose
from .io.calibration_file import load_calibration, save_calibration

__all__ = [
    "MG",
    "MODELS",
    "STANDARD_GRAVITY",
    "Calibration",
    "CalibrationError",
    "FitResult",
    "Pose",
    "Quality",
    "Sigma",
    "fit",
    "load_calibration",
    "save_calibration",
]
