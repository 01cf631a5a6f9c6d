"""The poses held while a sensor warmed, put back at the warm-up curves' reference temperature. The detector
makes poses of a warm-up too (one orientation, its mean drifting with the temperature); a sphere fit of them
as they are takes the drift for a scale and a misalignment, and one orientation held over 30 degC of warming
weighs as many poses. With the curves known, each pose's drift between its mean temperature and the reference
comes off, and the poses are fitted again (the node's /calibrate and replay --warmup both do)."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from .calibration import Calibration
from .pose import Pose
from .units import MG

# A pose whose drift from the curves' reference is below this is taken as it is (noise, not drift).
POSE_DRIFT_MPS2 = 0.1 * MG


def poses_at_reference(warmed: Calibration, poses: Sequence[Pose]) -> list[Pose] | None:
    """`poses` as the sensor would have given them at the curves' reference temperature (the warm-up's drift
    between a pose's mean temperature and the reference taken off its mean), or None when none drifted.
    `warmed`: a calibration with the curves as its (spline) temperature model. A pose is shifted by the curve
    at its mean temperature: one held over a fast rise keeps the curve's curvature over its span."""
    model = warmed.temperature
    if model is None or model.kind != "spline":
        return None
    reference = np.array([model.reference_degc])
    drift_ref, scale_ref = model.bias_and_scale(reference)
    out, moved = [], False
    for pose in poses:
        if pose.temperature_degc is None:
            out.append(pose)
            continue
        drift, scale = model.bias_and_scale(np.array([pose.temperature_degc]))
        shifted = warmed.bias + drift_ref[0] + (pose.accel_mps2 - warmed.bias - drift[0]) * scale_ref[0] / scale[0]
        moved = moved or bool(np.max(np.abs(shifted - pose.accel_mps2)) > POSE_DRIFT_MPS2)
        out.append(replace(pose, accel_mps2=shifted))
    return out if moved else None
