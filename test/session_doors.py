"""The two doors into a CalibrationSession that the tests compare: the node's (one message at a time) and
replay's (the whole recording). One copy here, so every test feeds the session the same way."""
from __future__ import annotations

import numpy as np

from accel_calibration.core.session import CalibrationSession


def per_message(session: CalibrationSession, t_ns, accel, gyro, temperatures=None, collecting=None,
                reason: str = "armed", store: bool = True) -> list:
    """What the node does: temperature and IMU messages in arrival order (a reading goes in before the
    first sample stamped at or after it), one add_sample each, then flush(). `collecting` (one bool per
    message, optional): collection paused where False, as the armed input or calibration/pause does
    (set_collecting at each change, for `reason`). `store`: the poses go into the store too."""
    stamps, values = temperatures if temperatures is not None else (np.zeros(0, dtype=np.int64), np.zeros(0))
    stamps, values = np.asarray(stamps, dtype=np.int64).tolist(), np.asarray(values, dtype=float).tolist()
    t = np.asarray(t_ns, dtype=np.int64).tolist()
    a, g = np.asarray(accel, dtype=float).tolist(), np.asarray(gyro, dtype=float).tolist()
    on = None if collecting is None else np.asarray(collecting, dtype=bool).tolist()
    poses = []
    k = 0
    for i in range(len(t)):
        while k < len(stamps) and stamps[k] <= t[i]:
            session.add_temperature(stamps[k], values[k])
            k += 1
        if on is not None and on[i] != session.collecting:
            session.set_collecting(on[i], reason)
        pose = session.add_sample(t[i], *a[i], *g[i])
        if pose is not None:
            poses.append(pose)
    last = session.flush()
    if last is not None:
        poses.append(last)
    if store:
        for pose in poses:
            session.add_pose(pose)
    return poses
