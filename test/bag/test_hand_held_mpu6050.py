"""A real hand-held MPU-6050 (sunsided/sensor-fusion, Imu + Temperature, stamps in bursts): four orientations
held by hand, never set down. The session's noise limits refuse every window; the refusal names the limits
and how to allow them, and once allowed, replay (both storages), the node's door and the detector alone
find the same poses and refuse the fit for the orientations missing."""
from __future__ import annotations

import re

import numpy as np
import pytest

from accel_calibration.core.settings import Settings
from accel_calibration.core.stream.detector import StaticDetector
from accel_calibration.live.calibration_work import LiveCalibration

from helpers.one_line import assert_one_error_line, run_main
from helpers.real_bags import read_imu_and_temperature
from helpers.session_doors import LogLines

STORAGES = ["sunsided_full_sphere_imu_temp_sqlite3", "sunsided_full_sphere_imu_temp_mcap_zstd"]
FEED_PERIOD_NS = 200_000_000  # the node's worker period


def detector_alone(bag):
    """StaticDetector with no noise limits, the latest temperature held at each IMU stamp."""
    latest = np.clip(np.searchsorted(bag.temperature_stamps_ns, bag.imu_stamps_ns, side="right") - 1, 0, None)
    return StaticDetector().process(bag.imu_stamps_ns, bag.imu[:, :3], bag.imu[:, 3:], bag.temperature[latest])


def allowance(message: str) -> list[str]:
    """The `-p NAME:=VALUE` arguments the refusal gives to take the sensor as it is."""
    said = re.search(r"to take this sensor as it is: ((?:-p \S+:=[0-9.]+ ?)+)", message)
    assert said is not None, message
    return said.group(1).split()


def replayed_poses(tmp_path, name, path, *arguments):
    out = tmp_path / f"{name}.csv"
    code, err = run_main(["replay", path, "--ignore-flight-state", "--poses-out", out, *arguments])
    rows = np.genfromtxt(out, delimiter=",", names=True, dtype=None, encoding="utf-8") if out.exists() else None
    return code, err, rows


@pytest.mark.parametrize("name", STORAGES)
def test_replay_names_the_limit_that_refused_the_sensor_and_how_to_allow_it(shared, tmp_path, name):
    path = shared(f"real/bags/{name}")
    code, err, _ = replayed_poses(tmp_path, name, path)
    assert_one_error_line(code, err, "found 0 static poses", "hardly ever still")
    # The accelerometer's quietest windows, 15.7 mg rms per axis, are above its limit of 15 mg.
    assert re.search(r"static\.max_noise_mg refused every window \(its quietest 15\.\d mg\)", err), err
    assert "static.max_gyro_noise_mradps" in err.split("refused")[1], err
    arguments = allowance(err)
    assert {a.split(":=")[0] for a in arguments[1::2]} == {"static.max_noise_mg", "static.max_gyro_noise_mradps"}

    bag = read_imu_and_temperature(path)
    expected = detector_alone(bag)
    assert len(expected) == 17
    faces = {tuple(np.round(p.accel_mps2 / 9.8).astype(int)) for p in expected}
    assert faces == {(0, 0, -1), (0, -1, 0), (0, 0, 1), (0, 1, 0)}  # four orientations, by hand
    code, err, rows = replayed_poses(tmp_path, name, path, *arguments)
    assert_one_error_line(code, err, "found 17 static poses", "no pose with x pointing up",
                          "no pose with x pointing down")
    assert rows["start_ns"].tolist() == [p.start_ns for p in expected]
    assert rows["end_ns"].tolist() == [p.end_ns for p in expected]
    np.testing.assert_allclose(np.column_stack([rows["ax"], rows["ay"], rows["az"]]),
                               [p.accel_mps2 for p in expected], rtol=0, atol=1e-9)


def fed_live(tmp_path, bag, parameters, period_ns):
    """LiveCalibration (the node without ROS) fed every message in the order it was logged, its worker
    feeding every `period_ns` of log time; (the poses it took, /calibrate's answer, the pose held at the end)."""
    live = LiveCalibration(Settings.from_parameters(parameters), tmp_path / "cal.yaml", LogLines())
    live.start()
    poses, next_feed = [], bag.arrival[0][0] + period_ns
    for log_ns, is_imu, row in bag.arrival:
        if log_ns >= next_feed:
            poses += live.feed()
            next_feed = log_ns + period_ns
        if is_imu:
            live.stream.buffer_imu(int(bag.imu_stamps_ns[row]), *bag.imu[row].tolist())
        else:
            live.stream.take_temperature(int(bag.temperature_stamps_ns[row]), float(bag.temperature[row]))
    poses += live.feed()
    success, message = live.calibrate()
    return poses, success, message, live.session.detector.peek_open()


def test_the_nodes_path_agrees_with_replay_at_the_defaults_and_once_allowed(shared, tmp_path):
    """At the defaults the node's /calibrate refuses as replay does, with the same limits and values; with
    them (the worker's 200 ms period), it takes the detector's poses: all but the last, which it holds
    when the recording stops and /calibrate counts."""
    path = shared(f"real/bags/{STORAGES[1]}")
    code, err, _ = replayed_poses(tmp_path, "default", path)
    arguments = allowance(err)
    bag = read_imu_and_temperature(path)
    poses, success, message, _ = fed_live(tmp_path, bag, {}, 5 * FEED_PERIOD_NS)  # a busy worker
    assert not poses and not success and allowance(message) == arguments, message
    parameters = {name: float(value) for name, value in (a.split(":=") for a in arguments[1::2])}
    poses, success, message, held = fed_live(tmp_path, bag, parameters, FEED_PERIOD_NS)
    expected = detector_alone(bag)
    assert [(p.start_ns, p.end_ns) for p in poses] == [(p.start_ns, p.end_ns) for p in expected[:-1]]
    assert (held.start_ns, held.end_ns) == (expected[-1].start_ns, expected[-1].end_ns)
    assert not success and "no pose with x pointing up" in message, message
