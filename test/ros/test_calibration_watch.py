"""The watch over real DDS: a node started with a calibration file of the sensor, then a session played
whose bias moved 5 mg on y; /diagnostics warns naming bias y, and nothing is applied by itself."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus

from accel_calibration.core.session import CalibrationSession
from accel_calibration.core.units import MG
from accel_calibration.io.calibration_file import load_calibration, save_calibration
from msg_tools.synthetic_imu import SyntheticImu, spread_orientations

from helpers.session_streams import stream

pytestmark = pytest.mark.ros
START_NS = 1_700_000_000 * 10**9


def test_a_bias_moved_5_mg_on_y_is_a_warn_naming_bias_y(tmp_path, tester, node_process):
    errors, samples = stream(seed=2, poses=16)
    session = CalibrationSession()
    for pose in session.add_recording(samples.t_ns, samples.accel_raw, samples.gyro_raw):
        session.add_pose(pose)
    verdict = session.calibrate()
    assert verdict.success, verdict.message
    save_calibration(verdict.calibration, tmp_path / "cal.yaml")
    node_process(tmp_path / "cal.yaml")
    tester.wait_ready()
    moved = dataclasses.replace(errors, bias_mps2=errors.bias_mps2 + np.array([0.0, 5 * MG, 0.0]))
    rng = np.random.default_rng(102)
    tester.play(SyntheticImu(moved, spread_orientations(10, rng), dwell_s=2.5, move_s=1.0, rate_hz=200.0,
                             seed=102).samples(), start_ns=START_NS)

    def warned():
        last = tester.diagnostics[-1] if tester.diagnostics else {}
        return last.get("calibration_watch", "").startswith("bias y +")

    assert tester.spin_until(warned, 30.0), tester.diagnostics[-1:] if tester.diagnostics else "no diagnostics"
    last = tester.diagnostics[-1]
    assert last["level"] == DiagnosticStatus.WARN and "calibration moved: bias y +" in last["message"]
    said = float(last["calibration_watch"].split(" mg")[0].removeprefix("bias y "))
    assert 3.5 < said < 6.5, last["calibration_watch"]
    assert ": recalibrate" in last["calibration_watch"]
    np.testing.assert_array_equal(load_calibration(tmp_path / "cal.yaml").bias, verdict.calibration.bias)
