"""PX4 ULog logs: the reader against pyulog on the real logs in ../shared/data/real/px4_ulog/, replay of
them through the session, logs written here (write_ulog) for what the real ones lack, and bad logs."""
from __future__ import annotations

import functools
import struct

import numpy as np
import pytest
from conftest import shared_path
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from pyulog import ULog

from accel_calibration import load_calibration
from accel_calibration.bag.recording import open_recording
from accel_calibration.bag.replay import ReplaySettings, replay_bag
from accel_calibration.bag.ulog_reader import UlogError, read_ulog
from accel_calibration.cli.main import main
from accel_calibration.core.session import CalibrationSession
from accel_calibration.core.settings import Settings
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations
from msg_tools.ulog_writer import sensor_combined_array, write_ulog

from helpers.one_line import refused

SAMPLE = "real/px4_ulog/sample.ulg"
TAGGED = "real/px4_ulog/sample_logging_tagged_and_default_params.ulg"


def xyz(data, names):
    return np.column_stack([data[n].astype(float) for n in names])


@pytest.mark.parametrize("name", [SAMPLE, TAGGED])
def test_reader_gives_exactly_pyuloggs_sensor_combined(shared, name):
    path = shared(name)
    data = ULog(str(path), ["sensor_combined"]).get_dataset("sensor_combined").data
    log = read_ulog(path)
    count = len(data["timestamp"])
    assert log.stream == "sensor_combined" and len(log.t_ns) == count > 2000
    accel = xyz(data, [f"accelerometer_m_s2[{i}]" for i in range(3)])
    gyro = xyz(data, [f"gyro_rad[{i}]" for i in range(3)])
    np.testing.assert_array_equal(log.accel_mps2, accel)  # float32 -> float64: exact
    np.testing.assert_array_equal(log.gyro_radps, gyro)
    for row in (0, count - 1):
        assert tuple(log.accel_mps2[row]) == tuple(float(v) for v in accel[row])
    stamps_us = data["timestamp"].astype(np.int64) + data["accelerometer_timestamp_relative"].astype(np.int64)
    np.testing.assert_array_equal(log.t_ns, stamps_us * 1000)
    assert np.all(np.diff(log.t_ns) > 0)  # monotonic, as PX4 logs them
    assert log.t_ns.dtype == np.int64 and log.accel_mps2.shape == (count, 3)


def test_second_log_per_instance_temperatures(shared):
    path = shared(TAGGED)
    full = ULog(str(path), ["sensor_accel", "sensor_gyro", "sensor_selection"])
    instances = sorted(d.multi_id for d in full.data_list if d.name == "sensor_accel")
    assert instances == [0, 1, 2]
    for instance in instances:
        accel = full.get_dataset("sensor_accel", instance).data
        gyro = full.get_dataset("sensor_gyro", instance).data
        log = read_ulog(path, instance=instance)
        assert log.stream == f"sensor_accel instance {instance}"
        assert log.sensor_id == f"px4 device {int(accel['device_id'][0])}"
        stamps, degc = log.temperature
        np.testing.assert_array_equal(stamps, accel["timestamp_sample"].astype(np.int64) * 1000)
        np.testing.assert_array_equal(degc, accel["temperature"].astype(float))  # 11 readings, this SITL log's 0 degC
        assert len(degc) == 11 and log.temperature_stream == f"sensor_accel instance {instance} temperature"
        np.testing.assert_array_equal(log.accel_mps2, xyz(accel, "xyz"))
        # The same chip's gyro, interpolated to the accel stamps (it is sampled 28 ms earlier here).
        g_us = gyro["timestamp_sample"].astype(np.int64)
        expected = np.column_stack([np.interp(accel["timestamp_sample"], g_us, gyro[a].astype(float)) for a in "xyz"])
        np.testing.assert_allclose(log.gyro_radps, expected, rtol=0, atol=1e-12)
    # sensor_combined is fed by the device sensor_selection names: its temperature is that instance's.
    selected = int(full.get_dataset("sensor_selection").data["accel_device_id"][-1])
    combined = read_ulog(path)
    assert combined.sensor_id == f"px4 device {selected}"
    assert combined.temperature_stream == "sensor_accel instance 0 temperature"
    assert len(combined.temperature[0]) == 11
    with pytest.raises(UlogError, match="no sensor_accel instance 3; the log has instance"):
        read_ulog(path, instance=3)


def test_sample_ulg_is_one_still_stretch_said_in_one_line(shared, tmp_path, capsys):
    poses_out, cal = tmp_path / "poses.csv", tmp_path / "cal.yaml"
    refused(capsys, ["replay", shared(SAMPLE), "--poses-out", poses_out, "-o", cal], "found 2 static poses",
            "(1 distinct direction) in sensor_combined (17070 samples, 68.9 s)", "sphere9 needs 12 orientations")
    assert not cal.exists()
    rows = poses_out.read_text().splitlines()
    header = rows[0].split(",")
    assert header[:9] == ["start_ns", "end_ns", "ax", "ay", "az", "gx", "gy", "gz", "samples"]
    table = [dict(zip(header, row.split(","))) for row in rows[1:]]
    assert [r["status"] for r in table] == ["not fitted", "not fitted"]
    # The stretch: from ~6.5 s after logging starts to the end (sample count and span), level within a degree.
    first, last = table[0], table[-1]
    assert int(first["start_ns"]) < 120e9 and int(last["end_ns"]) >= 181.4e9
    assert sum(int(r["samples"]) for r in table) > 15_000
    accel = np.array([float(first[a]) for a in ("ax", "ay", "az")])
    assert abs(np.linalg.norm(accel) - 9.7) < 0.1 and accel[2] < -9.5  # z down (PX4 body frame, FRD)
    assert all(abs(float(r["gx"])) < 0.01 for r in table)


def synthetic(seed=3, poses=14, rate_hz=250.0):
    rng = np.random.default_rng(seed)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    imu = SyntheticImu(errors, spread_orientations(poses, rng), dwell_s=2.5, move_s=1.0, rate_hz=rate_hz, seed=seed)
    return errors, imu.samples()


def write_session_ulog(path, samples, start_us=5_000_000, with_instance=False, temperature_degc=30.0):
    t_us = start_us + samples.t_ns // 1000
    topics = [("sensor_combined", 0, sensor_combined_array(t_us, samples.accel_raw, samples.gyro_raw))]
    if with_instance:  # a second IMU logged per instance, with a warming temperature
        accel = np.zeros(len(t_us), dtype=[("timestamp", "<u8"), ("timestamp_sample", "<u8"), ("device_id", "<u4"),
                                           ("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("temperature", "<f4")])
        gyro = np.zeros(len(t_us), dtype=[("timestamp", "<u8"), ("timestamp_sample", "<u8"), ("device_id", "<u4"),
                                          ("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
        for array in (accel, gyro):
            array["timestamp"], array["timestamp_sample"], array["device_id"] = t_us + 50, t_us, 77
        accel["x"], accel["y"], accel["z"] = samples.accel_raw.T
        gyro["x"], gyro["y"], gyro["z"] = samples.gyro_raw.T
        accel["temperature"] = temperature_degc + np.arange(len(t_us)) * 2e-5
        topics += [("sensor_accel", 1, accel), ("sensor_gyro", 1, gyro)]
    return write_ulog(path, topics)


def test_written_log_through_the_session_equals_the_python_api(tmp_path):
    errors, samples = synthetic()
    path = tmp_path / "flight.ulg"
    write_session_ulog(path, samples, with_instance=True)
    for instance in (None, 1):
        recording = open_recording(path, instance=instance)
        accel32 = samples.accel_raw.astype(np.float32).astype(float)  # what a log holds
        np.testing.assert_array_equal(recording.accel_mps2, accel32)
        session = CalibrationSession(Settings())
        poses = session.add_recording(recording.t_ns, accel32, samples.gyro_raw.astype(np.float32).astype(float),
                                      *(recording.temperature or (None, None)))
        for pose in poses:
            session.add_pose(pose)
        verdict = session.calibrate()
        assert verdict.success, verdict.message
        replay = replay_bag(path, ReplaySettings(instance=instance))
        assert [(p.start_ns, p.end_ns) for p in replay.poses] == [(p.start_ns, p.end_ns) for p in poses]
        np.testing.assert_allclose(replay.calibration.bias, verdict.calibration.bias, rtol=0, atol=1e-9)
        np.testing.assert_allclose(replay.calibration.matrix, verdict.calibration.matrix, rtol=0, atol=1e-9)
        # And the calibration is right: within 4 sigma of the truth.
        assert np.all(np.abs(replay.calibration.bias - errors.bias_mps2) <= 4 * replay.calibration.bias_sigma)
        if instance == 1:
            assert replay.calibration.sensor_id == "px4 device 77"
            assert all(p.temperature_degc is not None and 30.0 <= p.temperature_degc < 31.0 for p in replay.poses)


def test_corrected_copy_of_a_log_is_a_csv_of_corrected_samples(tmp_path, capsys):
    _, samples = synthetic(seed=5)
    path = tmp_path / "flight.ulg"
    write_session_ulog(path, samples)
    out, cal = tmp_path / "corrected.csv", tmp_path / "cal.yaml"
    assert main(["replay", str(path), "--corrected", str(out), "-o", str(cal)]) == 0
    assert "a ULog is not rewritten" in capsys.readouterr().out
    assert out.read_text().splitlines()[0] == "t_ns,ax,ay,az,gx,gy,gz"
    calibration = load_calibration(cal)
    again = replay_bag(out)  # the CSV reader takes it back; corrected samples need no more correction
    assert again.source.recording.format == "csv" and again.source.messages == len(samples.t_ns)
    np.testing.assert_allclose(again.source.recording.accel_mps2,
                               calibration.apply(samples.accel_raw.astype(np.float32).astype(float)),
                               rtol=0, atol=1e-12)
    assert np.abs(again.calibration.bias).max() < 1e-6


def test_log_without_accelerometer_topics_is_one_line_and_nothing_written(tmp_path, capsys):
    attitude = np.zeros(500, dtype=[("timestamp", "<u8"), ("q[0]", "<f4"), ("q[1]", "<f4"), ("q[2]", "<f4"),
                                    ("q[3]", "<f4")])
    attitude["timestamp"] = np.arange(500) * 4000
    path = tmp_path / "attitude_only.ulg"
    write_ulog(path, [("vehicle_attitude", 0, attitude)])
    outputs = [tmp_path / name for name in ("cal.yaml", "poses.csv", "corrected.csv")]
    for extra in ([], ["--instance", "0"]):
        assert main(["replay", str(path), "-o", str(outputs[0]), "--poses-out", str(outputs[1]),
                     "--corrected", str(outputs[2]), *extra]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "no accelerometer data" in err, err
    assert not any(p.exists() for p in outputs)


def record_starts(data: bytes) -> list[int]:
    """Where each ULog record starts (and the end of the file when the last one is whole)."""
    starts, pos = [], 16
    while pos + 3 <= len(data):
        starts.append(pos)
        pos += 3 + struct.unpack_from("<H", data, pos)[0]
    return starts + ([pos] if pos == len(data) else [])


@functools.cache
def sample_log() -> tuple[bytes, list[int]]:
    data = shared_path(SAMPLE).read_bytes()
    return data, record_starts(data)


@settings(max_examples=16, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(between_records=st.booleans(), fraction=st.floats(0.0, 1.0, exclude_max=True))
@example(between_records=True, fraction=0.0005)  # cut among the definitions: a nested type not yet defined
def test_a_log_cut_short_is_refused_in_one_line_unless_cut_between_records(tmp_path, between_records, fraction):
    sample_bytes, boundaries = sample_log()
    if between_records:
        cut = boundaries[int(fraction * len(boundaries))]
    else:
        cut = 17 + int(fraction * (len(sample_bytes) - 17))
    path = tmp_path / "cut.ulg"
    path.write_bytes(sample_bytes[:cut])
    if cut in boundaries:  # a whole, shorter log: read as far as it goes, the same samples as pyulog
        try:
            log = read_ulog(path)
        except UlogError as error:  # cut before the first sensor_combined message (or before anything)
            if cut == 16:
                assert "a file header and nothing after it" in str(error)
                return
            assert "no accelerometer data" in str(error)
            assert "sensor_combined" not in {d.name for d in ULog(str(path), ["sensor_combined"]).data_list}
            return
        expected = ULog(str(path), ["sensor_combined"]).get_dataset("sensor_combined").data
        assert len(log.t_ns) == len(expected["timestamp"])
        np.testing.assert_array_equal(log.accel_mps2[:, 2], expected["accelerometer_m_s2[2]"].astype(float))
        return
    cut_short = r"truncated ULog: (the record at byte \d+ (needs \d+ bytes|is cut short)|\d+ bytes)"
    with pytest.raises(UlogError, match=cut_short):
        read_ulog(path)


def test_truncated_log_is_one_line_and_nothing_written(tmp_path, capsys):
    sample_bytes, boundaries = sample_log()
    cut = boundaries[len(boundaries) // 2] + 7  # inside a record half way through
    path = tmp_path / "cut.ulg"
    path.write_bytes(sample_bytes[:cut])
    outputs = [tmp_path / "cal.yaml", tmp_path / "poses.csv"]
    refused(capsys, ["replay", path, "-o", outputs[0], "--poses-out", outputs[1]], "truncated ULog")
    assert not any(p.exists() for p in outputs)


@pytest.mark.parametrize("content, message", [
    (b"", "not a PX4 ULog"),
    (b"ULog\x01\x12\x35\x01", "truncated ULog: 8 bytes, shorter than the 16-byte file header"),
    (b"ULog\x01\x12\x35\x01" + bytes(8) + b"\xff\xff" + b"F" + b"x" * 40, "truncated ULog: the record at byte 16"),
    (b"ULog\x01\x12\x35\x01" + bytes(8) + b"\x05\x00" + b"\x00" + b"x" * 40, "corrupt ULog"),
    (b"ULog\x01\x12\x35\x01" + bytes(8) + b"\x28\x00B" + bytes(8) + b"\x02" + bytes(31), "unreadable ULog"),
])
def test_damaged_logs_are_one_line(tmp_path, capsys, content, message):
    path = tmp_path / "damaged.ulg"
    path.write_bytes(content)
    assert main(["replay", str(path)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
