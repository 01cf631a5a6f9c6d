"""What /diagnostics shows before the worker process has sent its first snapshot: the same keys as after,
so a reader of a counter or a value never finds it missing in the first seconds of a node's life."""
from __future__ import annotations

from accel_calibration.core.settings import Settings
from accel_calibration.live.calibration_work import LiveCalibration, starting_snapshot
from accel_calibration.live.per_message import imu_ring, temperature_ring

from helpers.session_doors import LogLines


def test_the_starting_snapshot_has_every_key_the_works_first_snapshot_has(tmp_path):
    path = tmp_path / "cal.yaml"
    work = LiveCalibration(Settings(), path, LogLines(), rings=(imu_ring(), temperature_ring()))
    work.start()
    first = work.snapshot()
    starting = starting_snapshot(Settings(), path, "/calibrate", ("warn", "no calibration yet"))
    assert set(first.counts) - set(starting.counts) == set()
    assert set(first.values) - set(starting.values) == set()
    assert all(count == 0 for count in starting.counts.values())
