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
    PLAUSIBILITY = "plausibility"  # the file's readers would put it in force (structure, handedness, the gyro's)
    PRIOR = "prior"  # the calibration in force can serve as the prior of a fit (its model, its sigma)


class GyroGate(enum.Enum):
    """The gyro fit's gates (core/gyro_gates.py), in the order a gyro fit meets them."""

    MOTIONS = "motions"  # enough usable motions between poses
    FIT = "fit"  # the fit converged, with the gyro's axes the accelerometer's and every axis turned about
    RESIDUAL = "residual"  # the motions reach the next pose
    SIGMA = "sigma"  # every parameter is known within its bound
    SCALE = "scale"  # each axis' gain is a MEMS gyro's in rad/s


# The gates a further pose can open: for them progress advises the orientation that helps most.
OPENED_BY_POSES = frozenset({Gate.POSES, Gate.FIT, Gate.SIGMA})


@dataclass(frozen=True)
class Refusal:
    gate: Gate
    text: str
    part: str = ""  # the part of a calibration refused, said first ("temperature block"); "" for the whole

    def __str__(self) -> str:
        return self.said()

    def said(self, gate_named: bool = True) -> str:
        """One line: the part, the gate (unless the reader's own words name it already) and the text."""
        said = f"gate {self.gate.value}: {self.text}" if gate_named else self.text
        return f"{self.part}: {said}" if self.part else said


@dataclass(frozen=True)
class GyroRefusal:
    """Why a gyro fit is not applied (the accelerometer's calibration stands)."""

    gate: GyroGate
    text: str

    def __str__(self) -> str:
        return f"gyro: gate {self.gate.value}: {self.text}"


class MotionProblem(enum.Enum):
    """Why a motion between two poses is not used by the gyro fit (core/gyro_fit.motion_problem), as counted."""

    NOT_RECORDED = "not recorded"  # the recorder holds no samples between the poses
    PAUSED = "paused"  # collection was paused during it
    SATURATED = "saturated"  # the gyro reached its range
    SCREENED = "screened"  # a sample was screened out, or the clock jumped
    TOO_SHORT = "too short"  # fewer than three samples
    NOT_FINITE = "not finite"
    STAMPS = "stamps"  # stamps not increasing
    LONG = "long"  # longer than gyro.max_motion_s
    GAP = "gap"  # a gap in its samples
    SPAN = "span"  # its samples do not reach from one pose to the next
