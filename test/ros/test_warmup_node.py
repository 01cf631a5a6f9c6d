"""calibration_node over real rclpy / Fast DDS learns a warm-up: a sensor still and level while it warms
(compressed in time: 15 -> 43 degC in 3 minutes of header time, played closed-loop), /diagnostics shows the
span, /calibrate adds the temperature curves on top of the calibration in force, and the corrected output
at rest then follows temperature: its bias against the truth across the range."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from accel_calibration import MG, load_calibration
from accel_calibration.io.calibration_file import save_calibration
from msg_tools.node_process import NodeProcess
from msg_tools.synthetic_imu import SyntheticSamples

from helpers.warmup_sessions import Heating, two_imus, warmup_recording

pytestmark = pytest.mark.ros

START_NS = 1_700_000_000 * 10**9
RATE_HZ = 200.0
HEATING = Heating(tau_s=60.0, minutes=3.0)  # at most 0.5 degC/s: the filter's 0.5 s lags it 0.25 degC
DWELL_S = 6.0  # each fresh temperature: the correction's filter settles, the last LAST_S are averaged
LAST_S = 2.0


def played(recording) -> SyntheticSamples:
    n = len(recording.t_ns)
    return SyntheticSamples(recording.t_ns, recording.accel_mps2, recording.gyro_radps, recording.temperature_degc,
                            np.zeros((n, 3)), np.ones(n, bool))


def mean_output(tester, recording, start_ns) -> tuple[np.ndarray, np.ndarray]:
    """Play a still dwell; the corrected output's mean over its last LAST_S: acceleration, angular rate."""
    tester.corrected.clear()
    sent = tester.play(played(recording), start_ns=start_ns)
    assert tester.settle(sent)
    last = start_ns + int((DWELL_S - LAST_S) * 1e9)
    window = [m for m in tester.corrected if m.header.stamp.sec * 10**9 + m.header.stamp.nanosec >= last]
    assert len(window) >= 0.99 * LAST_S * RATE_HZ
    accel = np.mean([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in window], 0)
    gyro = np.mean([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m in window], 0)
    return accel, gyro


def test_the_node_learns_a_warm_up_and_its_output_follows_temperature(tmp_path, tester):
    truth = two_imus()[0]
    rng = np.random.default_rng(11)
    cal_file = tmp_path / "cal.yaml"
    save_calibration(truth.calibration, cal_file)  # the calibration in force: the curves go on top of it
    node = NodeProcess(cal_file)
    try:
        tester.wait_ready()
        tester.play(played(warmup_recording(truth, rng, HEATING, rate_hz=RATE_HZ)), start_ns=START_NS)
        def ready() -> bool:
            return bool(tester.diagnostics) and tester.diagnostics[-1].get("warmup", "").startswith("ready")

        assert tester.spin_until(ready, 20), tester.diagnostics[-1] if tester.diagnostics else "no diagnostics"
        low, high = (float(v) for v in tester.diagnostics[-1]["warmup_span_degc"].split(".."))
        assert low < 16.0 and high > 40.0, tester.diagnostics[-1]["warmup_span_degc"]
        answer = tester.call("calibrate")
        assert answer.success, answer.message
        warmup = yaml.safe_load(answer.message)["warmup"]
        assert warmup["added"] is True and warmup["range_degc"][1] > 42.0, warmup
        assert load_calibration(cal_file).temperature.kind == "spline"

        reference = warmup["reference_degc"]
        temperatures = (reference, 17.0, 24.0, 31.0, 38.0, 42.0)
        outputs = []
        for i, degc in enumerate(temperatures):
            dwell = warmup_recording(truth, rng, Heating(start_degc=degc, end_degc=degc, minutes=DWELL_S / 60.0),
                                     rate_hz=RATE_HZ)
            outputs.append(mean_output(tester, dwell, START_NS + int((300.0 + 20.0 * i) * 1e9)))
        # One orientation sees the accelerometer's drift relative to the reference; the gyro's whole bias.
        accel_mg = max(np.abs(accel - outputs[0][0]).max() / MG for accel, _ in outputs[1:])
        gyro_mradps = max(np.abs(gyro).max() * 1e3 for _, gyro in outputs)
        raw_mg = np.ptp(truth.accel_drift(np.array(temperatures)), axis=0).max() / MG
        assert raw_mg > 20.0
        assert accel_mg < 1.5 and gyro_mradps < 0.3, (accel_mg, gyro_mradps, raw_mg)
    finally:
        assert node.stop() == 0, node.log()
