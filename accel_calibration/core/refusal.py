"""Why a fit is not applied, as a value: the gate that refused it and what it said. Callers decide by the
gate; the text is for people and is never parsed back."""
from __future__ import annotations

import enum
from dataclasses import dataclass


class Gate(enum.Enum):
    """The accelerometer's gates, in the order a verdict meets them, by the name a refusal says."""

    MOVED = "moved"  # no pose held is from before a move the watch of the calibration in force saw
    UNITS = "units"  # the stream is in m/s^2
    POSES = "poses"  # enough poses for the model
    FIT = "fit"  # the fit converged and observes every parameter
    RESIDUAL = "residual"  # the poses lie on the fitted sphere
    SIGMA = "sigma"  # every parameter is known within its bound
    BIAS = "bias"  # the bias is one a MEMS part can have
    SCALE = "scale"  # so is each axis' gain
    PLAUSIBILITY = "plausibility"  # the file's readers would put it in force


# The gates a further pose can open: for them progress advises the orientation that helps most.
OPENED_BY_POSES = frozenset({Gate.POSES, Gate.FIT, Gate.SIGMA})


@dataclass(frozen=True)
class Refusal:
    gate: Gate
    text: str

    def __str__(self) -> str:
        return f"gate {self.gate.value}: {self.text}"
