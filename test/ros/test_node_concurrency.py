"""/calibrate must not stop the corrected stream, and the correction
terms are written from two threads (temperature on the executor, a new calibration from the worker
process's pipe).

The node runs in this process (its real spin loop, real rclpy/DDS to a client node), so its worker
process can be frozen outright: the stream is shown to flow *while* the work is stopped in a calibrate,
with no timing luck involved."""
from __future__ import annotations

import os
import signal
import sys
import threading

import numpy as np
import pytest
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from accel_calibration.core.calibration import Calibration
from accel_calibration.core.correction import Correction
from accel_calibration.core.temperature_models import TemperatureModel
from accel_calibration.ros.node import CalibrationNode, spin_until
from msg_tools.conversions import make_imu
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

pytestmark = pytest.mark.ros
START_NS = 1_700_000_000 * 10**9


@pytest.fixture
def running_node(ros, tmp_path):
    """A CalibrationNode spun by its own spin loop in a thread; always stopped."""
    holder = {}

    def start(**parameters):
        overrides = [Parameter("calibration_file", value=str(tmp_path / "cal.yaml"))]
        overrides += [Parameter(name, value=value) for name, value in parameters.items()]
        node = CalibrationNode(parameter_overrides=overrides)
        stop = threading.Event()
        thread = threading.Thread(target=spin_until, args=(node, stop), daemon=True)
        thread.start()
        holder.update(node=node, stop=stop, thread=thread)
        assert node._worker.submit("ping").result(timeout=60) == (True, "")  # the work has started
        return node

    yield start
    if holder:
        holder["stop"].set()
        holder["thread"].join(timeout=10)
        holder["node"].close()
        holder["node"].destroy_node()


def _session_samples(seed=5, poses=16):
    errors = SensorErrors.mpu6050_like(np.random.default_rng(seed), noise_mps2=0.02)
    imu = SyntheticImu(errors, spread_orientations(poses, np.random.default_rng(seed + 1)), dwell_s=2.5, move_s=1.0,
                       rate_hz=200.0, seed=seed)
    return errors, imu.samples()


def test_corrected_stream_flows_while_the_work_is_frozen_in_a_calibrate(running_node, tester, tmp_path):
    """The work (fit, save) runs in the worker process: frozen outright (SIGSTOP) with /calibrate
    pending, the stream still carries every message, raw until the work saves and puts the calibration
    in force, corrected by it after."""
    node = running_node()
    errors, samples = _session_samples()
    # The session goes in through the Imu callback (what playback would give, without its DDS traffic).
    for i in range(len(samples.t_ns)):
        node._imu.take(make_imu(START_NS + int(samples.t_ns[i]), samples.accel_raw[i], samples.gyro_raw[i]))
    assert node._worker.submit("ping").result(timeout=60) == (True, "")  # it has every sample
    tester.wait_ready()

    worker = node._worker._process.pid
    os.kill(worker, signal.SIGSTOP)
    try:
        future = tester.clients["calibrate"].call_async(Trigger.Request())
        before = len(tester.corrected)
        sent = tester.play(samples, start_ns=START_NS + 10**12, indices=range(0, 400))
        assert len(tester.corrected) - before >= sent == 400
        assert not future.done(), "/calibrate answered while the work was frozen"
        assert node._stream.in_force.calibration is None and not (tmp_path / "cal.yaml").exists()
        # Raw passes through untouched while nothing is in force.
        np.testing.assert_allclose([m.linear_acceleration.z for m in tester.corrected[before:before + 5]],
                                   samples.accel_raw[:5, 2])
    finally:
        os.kill(worker, signal.SIGCONT)
    assert tester.spin_until(future.done, 60)
    assert future.result().success, future.result().message
    assert (tmp_path / "cal.yaml").exists()
    np.testing.assert_allclose(node._stream.in_force.calibration.bias, errors.bias_mps2, atol=0.005)

    # And after it: the stream is corrected by what was saved.
    before = len(tester.corrected)
    tester.play(samples, start_ns=START_NS + 2 * 10**12, indices=range(0, 50), temperature=False)
    first = tester.corrected[before].linear_acceleration
    expected = node._stream.in_force.calibration.apply(samples.accel_raw[0])
    np.testing.assert_allclose([first.x, first.y, first.z], expected, atol=1e-9)


def test_correction_is_never_torn_between_temperature_and_a_new_calibration(running_node):
    """Temperature updates (executor) and installs (worker) both rebuild the correction: whatever
    interleaving, the correction in force is always the one built from the calibration in force and
    the filtered temperature, never a mix of an old calibration with a new temperature."""
    node = running_node()
    rng = np.random.default_rng(3)
    # Each with its own temperature drift, so a correction built from one calibration and another's
    # moment would be visibly wrong.
    calibrations = [Calibration(model="sphere9", bias=rng.normal(0, 0.05, 3),
                                matrix=np.eye(3) + np.tril(rng.normal(0, 0.01, (3, 3))),
                                reference_temperature_degc=25.0,
                                temperature=TemperatureModel(kind="polynomial", reference_degc=25.0,
                                                             range_degc=(0.0, 60.0),
                                                             bias_coefficients=rng.normal(0, 0.01, (1, 3))))
                    for _ in range(20)]
    torn = 0
    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # threads interleave every few bytecodes: a race shows within the run
    try:
        k = 0
        for round_ in range(150):
            batch = calibrations[round_ % 7: round_ % 7 + 4]
            installer = threading.Thread(target=lambda batch=batch: [node._stream.in_force.install(c) for c in batch])
            installer.start()
            for _ in range(30):  # the executor side meanwhile: temperature readings
                k += 1
                node._on_temperature(_temperature(START_NS + k * 10**8, 20.0 + (k % 40) * 0.5))
            installer.join()
            # At rest, the correction in force is the calibration in force at the temperature it
            # says it was evaluated at: never an older calibration written back by the other thread.
            calibration, correction = node._stream.in_force.calibration, node._stream.in_force.correction
            expected = Correction.build(calibration, correction.temperature_degc)
            if not np.allclose(correction.apply(1.0, 2.0, 9.0), expected.apply(1.0, 2.0, 9.0), atol=1e-12):
                torn += 1
    finally:
        sys.setswitchinterval(switch)
    assert torn == 0, f"{torn} of 150 rounds left a correction built from another calibration"
    # And it follows the temperature: once the readings stop, the terms are those of the last one.
    node._on_temperature(_temperature(START_NS + 2001 * 10**8, 45.0))
    in_force = node._stream.in_force
    assert in_force.correction.temperature_degc == in_force.temperature_degc
    final = Correction.build(in_force.calibration, in_force.temperature_degc)
    assert in_force.correction.apply(1.0, 2.0, 9.0) == final.apply(1.0, 2.0, 9.0)


def _temperature(stamp_ns, degc):
    from sensor_msgs.msg import Temperature

    msg = Temperature()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    msg.temperature = degc
    return msg


def test_a_message_in_another_frame_than_the_calibration_is_warned_and_counted(running_node):
    node = running_node()
    node._stream.install(Calibration(bias=np.zeros(3), matrix=np.eye(3), frame_id="imu_link"))
    node._stream.set_frame_id("imu_link")
    assert node.counters().get("frame_id_mismatch", 0) == 0
    node._stream.set_frame_id("camera_imu_optical_frame")
    counts = node.counters()
    assert counts["frame_id_mismatch"] == 1 and counts["frame_id_changes"] == 1
    # A calibration made in the new frame stops the warnings.
    node._stream.in_force.install(Calibration(bias=np.zeros(3), matrix=np.eye(3), frame_id="camera_imu_optical_frame"))
    node._stream.check_frame()
    assert node.counters()["frame_id_mismatch"] == 1


def test_a_service_callback_that_raises_answers_failure_and_the_node_carries_on(running_node, tester):
    """The fault is planted where only calibration/get reads it and stays in place across a diagnostics tick:
    a fault planted in shared state (the calibration in force) is read by the 1 Hz diagnostics timer too,
    whose failure was then counted beside the service's whenever the call took longer than the time to the
    next tick (a loaded machine)."""
    node = running_node()
    tester.wait_ready()

    def raising_calibration_text():
        raise AttributeError("planted")

    node._stream.calibration_text = raising_calibration_text
    seen = len(tester.diagnostics)
    answer = tester.call("calibration/get")
    assert not answer.success and answer.message.startswith("internal error (AttributeError")
    # A diagnostics tick with the fault still in place does not touch it: only the service's callback failed.
    assert tester.spin_until(lambda: len(tester.diagnostics) >= seen + 2, 20)
    assert dict(node._boundary.errors) == {"calibration/get": 1}
    assert node.counters()["callback_errors"] == 1
    del node._stream.calibration_text
    assert not tester.call("calibration/get").success  # still answering, now the ordinary refusal
    assert tester.call("calibration/enable", data=True).success


def test_a_worker_process_that_dies_is_started_again_and_the_stream_never_stops(running_node, tester):
    node = running_node()
    _, samples = _session_samples(poses=4)
    tester.wait_ready()
    os.kill(node._worker._process.pid, signal.SIGKILL)
    before = len(tester.corrected)
    sent = tester.play(samples, start_ns=START_NS, indices=range(0, 300))
    assert len(tester.corrected) - before >= sent == 300
    assert tester.spin_until(lambda: node._worker.restarts == 1 and node._worker.alive, 60)
    assert node._worker.submit("ping").result(timeout=60) == (True, "")
    assert node.counters()["worker_restarts"] == 1
    answer = tester.call("calibrate")  # the new work answers (too few poses yet), the node carries on
    assert not answer.success and answer.message.startswith("not calibrated")


class _LoggedLines:
    """In place of the worker's logger: every line kept (rclpy refuses one call site of several severities)."""

    def __init__(self):
        self.lines = []

    def __getattr__(self, level):
        return lambda message, **kwargs: self.lines.append(message)


def test_a_calibrate_while_the_worker_is_started_again_after_a_second_death_is_answered(running_node, tester):
    """After a second death the work is started again only after a pause: a /calibrate asked meanwhile is
    answered at once, `success: false` with the reason, and one asked after is answered by the new work."""
    node = running_node()
    tester.wait_ready()
    logged = node._worker._log = _LoggedLines()
    for death in (1, 2):
        os.kill(node._worker._process.pid, signal.SIGKILL)
        # The node has seen the death and is about to start the work again (after the pause, the second time).
        assert tester.spin_until(lambda death=death: sum("restarting it" in line for line in logged.lines) == death,
                                 60)
        if death == 1:
            assert tester.spin_until(lambda: node._worker.restarts == 1 and node._worker.alive, 60)
            assert node._worker.submit("ping").result(timeout=60) == (True, "")
    answer = tester.call("calibrate", timeout=3.0)  # before the pause ends: not by the new work
    assert not answer.success and "started again" in answer.message, answer.message
    assert tester.spin_until(lambda: node._worker.restarts == 2 and node._worker.alive, 60)
    assert node._worker.submit("ping").result(timeout=60) == (True, "")
    answer = tester.call("calibrate")
    assert not answer.success and answer.message.startswith("not calibrated"), answer.message
