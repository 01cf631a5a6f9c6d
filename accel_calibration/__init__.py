"""Online MEMS accelerometer calibration.

The core -- models, Gauss-Newton fit, static detector, calibration files -- imports no ROS; the
node (`calibration_node`), bag replay and the CLI are adapters over it.
Convention everywhere: SI units and a_true = M (a_raw - b).
"""
from .calibration import MG, STANDARD_GRAVITY, Calibration, Quality
from .errors import CalibrationError
from .fit import FitResult, Sigma, fit
from .models import MODELS
from .pose import Pose

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
]
