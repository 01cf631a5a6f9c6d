"""Over real DDS: calibration/pause (SetBool) and the `armed` input (std_msgs/Bool) stop collection while
the corrected stream keeps flowing; /diagnostics says why; collection resumes by itself. Playback is
closed-loop (each chunk echoed before the next); state changes are awaited on /diagnostics, never slept on."""
from __future__ import annotations

import numpy as np
import pytest
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Bool
from std_srvs.srv import SetBool

from accel_calibration.core.session import CalibrationSession
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, SyntheticSamples, spread_orientations

from helpers.session_doors import per_message

pytestmark = pytest.mark.ros
START_NS = 1_700_000_000 * 10**9
DWELL_S, MOVE_S, RATE_HZ = 2.5, 1.0, 200.0


def part(samples, first, stop):
    return SyntheticSamples(*(getattr(samples, name)[first:stop] for name in
                              ("t_ns", "accel_raw", "gyro_raw", "temperature_degc", "accel_true", "static")))


def in_process_poses(samples, bounds, collecting):
    """What the node should hold: the same messages through a session paused where `collecting` says."""
    session = CalibrationSession()
    mask = np.concatenate([np.full(stop - first, on) for (first, stop), on in zip(bounds, collecting)])
    stop = bounds[-1][1]
    per_message(session, START_NS + samples.t_ns[:stop], samples.accel_raw[:stop], samples.gyro_raw[:stop],
                collecting=mask)
    return len(session.store)


def test_pause_and_armed_stop_collection_while_the_stream_flows(tmp_path, tester, node_process):
    node = node_process(tmp_path / "cal.yaml")
    tester.wait_ready()
    pause = tester.node.create_client(SetBool, "calibration/pause")
    armed = tester.node.create_publisher(Bool, "armed", QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                                                                   history=HistoryPolicy.KEEP_LAST))
    assert pause.wait_for_service(timeout_sec=20)
    errors = SensorErrors.mpu6050_like(np.random.default_rng(21), noise_mps2=0.02)
    rotations = spread_orientations(20, np.random.default_rng(22))
    samples = SyntheticImu(errors, rotations, dwell_s=DWELL_S, move_s=MOVE_S, rate_hz=RATE_HZ, seed=21).samples()
    # Four parts of five orientations each, cut in the middle of a turn (no still interval open at a cut).
    cuts = [0, *[int(((k * 5 - 1) * (DWELL_S + MOVE_S) + DWELL_S + MOVE_S / 2) * RATE_HZ) for k in (1, 2, 3)],
            len(samples.t_ns)]
    bounds = list(zip(cuts[:-1], cuts[1:]))

    def diagnostics(key, value, timeout=20.0):
        assert tester.spin_until(lambda: bool(tester.diagnostics) and tester.diagnostics[-1].get(key) == value,
                                 timeout), (key, value, tester.diagnostics[-1:] and tester.diagnostics[-1].get(key))
        return tester.diagnostics[-1]

    def set_pause(data):
        future = pause.call_async(SetBool.Request(data=data))
        assert tester.spin_until(future.done, 20)
        return future.result()

    sent = tester.play(part(samples, *bounds[0]), start_ns=START_NS)  # collected
    first = in_process_poses(samples, bounds[:1], [True])
    diagnostics("poses", str(first))

    answer = set_pause(True)
    assert answer.success and "paused" in answer.message
    status = diagnostics("collecting", "paused (calibration/pause)")
    assert "collection paused: calibration/pause" in status["message"]
    sent += tester.play(part(samples, *bounds[1]), start_ns=START_NS)  # echoed, corrected: not collected
    paused_samples = bounds[1][1] - bounds[1][0]
    diagnostics("samples_paused", str(paused_samples))
    answer = set_pause(False)
    assert answer.success and answer.message == "collection resumed"
    diagnostics("collecting", "yes")

    sent += tester.play(part(samples, *bounds[2]), start_ns=START_NS)  # collected again
    armed.publish(Bool(data=True))
    diagnostics("collecting", "paused (armed)")
    sent += tester.play(part(samples, *bounds[3]), start_ns=START_NS)  # the vehicle is armed: not collected
    diagnostics("samples_paused", str(paused_samples + bounds[3][1] - bounds[3][0]))
    armed.publish(Bool(data=False))
    diagnostics("collecting", "yes")

    expected = in_process_poses(samples, bounds, [True, False, True, False])
    assert expected < in_process_poses(samples, bounds, [True] * 4) - 5  # the paused parts held poses
    status = diagnostics("poses", str(expected))
    assert status["level"] != 2 and len(tester.corrected) >= sent  # every message came back corrected
    assert node.stop() == 0 and "Traceback" not in node.log()
