"""Online MEMS accelerometer calibration.

The core -- models, Gauss-Newton fit, static detector, calibration files -- imports no ROS; the
node (`calibration_node`), bag replay and the CLI are adapters over it.
Convention everywhere: SI units and a_true = M (a_raw - b).

The names below are imported on first use (PEP 562): importing a subpackage (the CLI's entry module,
the node) does not import the fit and the calibration files it may not need.
"""
from __future__ import annotations

import importlib
from typing import Any

_FROM = {
    "MG": ".core.units", "STANDARD_GRAVITY": ".core.units", "Calibration": ".core.calibration",
    "Quality": ".core.calibration", "CalibrationError": ".core.errors", "FitResult": ".core.fit",
    "Sigma": ".core.fit", "fit": ".core.fit", "MODELS": ".core.models", "Pose": ".core.pose",
    "load_calibration": ".io.calibration_file", "save_calibration": ".io.calibration_file",
}

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


def __getattr__(name: str) -> Any:
    module = _FROM.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value  # the next access is a plain attribute
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
