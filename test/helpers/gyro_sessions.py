"""Simulated hand-turned sessions (msg_tools.synthetic_motion) as the gyro fit's inputs: the still
poses as detected (time order) and the raw gyro of each motion between them."""
from __future__ import annotations

import numpy as np

from accel_calibration.core.gyro_fit import Motion
from accel_calibration.core.pose import Pose
from msg_tools.synthetic_motion import MotionSession


def poses_and_motions(session: MotionSession, margin_s: float = 0.2) -> tuple[list[Pose], list[Motion]]:
    """Poses from each still range shrunk by `margin_s` at both ends (a detector's window does about
    that), motions from the last sample of one pose to the first of the next."""
    margin = int(round(margin_s * session.rate_hz))
    poses, bounds = [], []
    for first, last in session.still:
        first, last = first + margin, last - margin
        accel = session.accel_mps2[first:last + 1]
        gyro = session.gyro_radps[first:last + 1]
        poses.append(Pose(accel_mps2=accel.mean(axis=0), accel_cov=np.cov(accel.T), samples=len(accel),
                          start_ns=int(session.stamps_ns[first]), end_ns=int(session.stamps_ns[last]),
                          gyro_radps=gyro.mean(axis=0)))
        bounds.append((first, last))
    motions = [Motion(session.stamps_ns[bounds[i][1]:bounds[i + 1][0] + 1],
                      session.gyro_radps[bounds[i][1]:bounds[i + 1][0] + 1]) for i in range(len(bounds) - 1)]
    return poses, motions
