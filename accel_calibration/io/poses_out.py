"""The still intervals a replay found, as a CSV pose table (`accel-calib replay --poses-out`), which
`accel-calib fit` and `report --poses` read back (io.pose_table: ax,ay,az and temperature are the
columns they use; the others say where each pose came from and what the fit made of it).

Columns: start_ns,end_ns (the recording's stamps), ax,ay,az (mean raw acceleration, m/s^2), gx,gy,gz
(mean angular rate, rad/s; empty without a gyro), samples, sigma_mg (the mean's own 1-sigma noise per axis,
mg: the samples' rms spread over sqrt(samples), 0 when unknown; `fit` weights the poses by it),
temperature,temperature_spread (mean and
max - min, degC; only when the recording has a temperature, empty for a pose without one), status
(used / outlier by the fit, dropped by the full pose store, not fitted).
"""
from __future__ import annotations

import csv
import io
from collections.abc import Sequence

from ..core.fit import pose_mean_sigma
from ..core.pose import Pose
from ..core.pose_map import PoseStatus
from ..core.units import MG

STATUSES = tuple(status.value for status in PoseStatus if status is not PoseStatus.MERGED)


def poses_table_text(poses: Sequence[Pose], statuses: Sequence[PoseStatus]) -> str:
    if len(poses) != len(statuses):
        raise ValueError(f"{len(poses)} poses but {len(statuses)} statuses")
    with_temperature = any(p.temperature_degc is not None for p in poses)
    header = ["start_ns", "end_ns", "ax", "ay", "az", "gx", "gy", "gz", "samples", "sigma_mg"]
    header += ["temperature", "temperature_spread"] if with_temperature else []
    header.append("status")
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(header)
    for pose, status, sigma in zip(poses, statuses, pose_mean_sigma(poses)):
        row = [str(int(pose.start_ns)), str(int(pose.end_ns)), *(repr(float(v)) for v in pose.accel_mps2)]
        row += [repr(float(v)) for v in pose.gyro_radps] if pose.gyro_radps is not None else ["", "", ""]
        row.append(str(int(pose.samples)))
        row.append(repr(float(sigma) / MG))
        if with_temperature:
            row += [_number(pose.temperature_degc), _number(pose.temperature_spread_degc)]
        row.append(status.value)
        writer.writerow(row)
    return out.getvalue()


def _number(value: float | None) -> str:
    return "" if value is None else repr(float(value))
