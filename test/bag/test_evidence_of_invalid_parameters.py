"""A flight log whose calibration parameters of one IMU are there but invalid: that IMU's flight evidence is
"none" with the reason naming the parameter, the other IMUs' evidence as ever (never an exception)."""
from __future__ import annotations

from accel_calibration.bag.flight_evidence import log_evidence

from helpers.autopilot_logs import DEVICES, simulate, write_px4_log


def test_an_imu_whose_px4_scale_is_out_of_range_is_evidence_none_naming_it(tmp_path):
    log = tmp_path / "scale5.ulg"
    write_px4_log(log, simulate(39), changed={"CAL_ACC1_XSCALE": 5.0})
    first, second = log_evidence(str(log))
    assert first.device == str(DEVICES[0]) and "CAL_ACC1" not in first.reason
    assert second.verdict == "none" and "CAL_ACC1_XSCALE = 5 is outside the range" in second.reason, second
