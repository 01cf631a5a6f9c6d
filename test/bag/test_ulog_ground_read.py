"""A PX4 ULog read a block at a time (bag/ulog_stream.py) gives every field pyulog gives, and a read of the
ground only (the fleet's flight evidence) gives the same poses as the whole log while keeping a fraction of it."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pyulog import ULog

from accel_calibration.bag.replay import ReplaySettings, replay_bag
from accel_calibration.bag.ulog_pass import ground_samples
from accel_calibration.bag.ulog_reader import UlogError
from accel_calibration.bag.ulog_stream import stream_topics

import helpers.flight_logs as logs
from helpers.flight_logs import fly, sensors, true_in_force, write_ulog_flight

TOPICS = ["sensor_accel", "sensor_gyro", "sensor_combined", "vehicle_status", "estimator_sensor_bias",
          "vehicle_land_detected"]


@pytest.fixture(scope="module")
def flight_ulog(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("ground") / "flight.ulg"
    truths = sensors(41, 3)
    write_ulog_flight(path, fly(truths, 41), [true_in_force(t) for t in truths])
    return path


def _streamed(path: Path, block_bytes: int) -> dict[tuple[str, int], dict[str, np.ndarray]]:
    parts: dict[tuple[str, int], list[dict[str, np.ndarray]]] = {}
    for block in stream_topics(path, set(TOPICS), block_bytes):
        for subscription, columns in block:
            parts.setdefault((subscription.name, subscription.multi_id), []).append(columns)
    return {key: {k: np.concatenate([p[k] for p in found]) for k in found[0]} for key, found in parts.items()}


def _assert_as_pyulog(path: Path, block_bytes: int) -> int:
    log = ULog(str(path), TOPICS)
    mine = _streamed(path, block_bytes)
    compared = 0
    for dataset in log.data_list:
        columns = mine.pop((dataset.name, dataset.multi_id))
        assert set(columns) == set(dataset.data), dataset.name
        for name, values in dataset.data.items():
            np.testing.assert_array_equal(columns[name], values, err_msg=f"{dataset.name}.{name}")
            compared += 1
    assert not mine, f"topics pyulog does not give: {sorted(mine)}"
    return compared


@pytest.mark.parametrize("name", ["sample.ulg", "sample_logging_tagged_and_default_params.ulg"])
def test_real_px4_logs_read_a_block_at_a_time_equal_pyulog_field_by_field(name: str) -> None:
    path = shared_path(f"real/px4_ulog/{name}")
    assert _assert_as_pyulog(path, 1 << 14) > 30  # nested formats and arrays included (estimator_sensor_bias)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(block_bytes=st.integers(min_value=64, max_value=1 << 18))
def test_the_block_size_changes_nothing(flight_ulog: Path, block_bytes: int) -> None:
    assert _assert_as_pyulog(flight_ulog, block_bytes) >= 40


@pytest.mark.parametrize("instance", [None, 0, 2])
def test_a_ground_read_gives_the_poses_of_the_whole_log(flight_ulog: Path, instance: int | None) -> None:
    whole = replay_bag(flight_ulog, ReplaySettings(instance=instance))
    ground = replay_bag(flight_ulog, ReplaySettings(instance=instance, ground_only=True))
    kept = len(ground.source.recording.t_ns)
    assert kept < 0.8 * len(whole.source.recording.t_ns)  # the flight is left out
    assert ground.source.messages == whole.source.messages  # and still counted, as the whole log's
    assert ground.source.duration_s == pytest.approx(whole.source.duration_s)
    assert len(whole.poses) >= 1 and len(ground.poses) == len(whole.poses)
    for a, b in zip(whole.poses, ground.poses, strict=True):
        assert (a.start_ns, a.end_ns, a.samples) == (b.start_ns, b.end_ns, b.samples)
        np.testing.assert_allclose(b.accel_mps2, a.accel_mps2, rtol=0, atol=1e-9)  # m/s^2: summed in other parts
        np.testing.assert_allclose(b.gyro_radps, a.gyro_radps, rtol=0, atol=1e-12)
        assert b.temperature_degc == pytest.approx(a.temperature_degc, abs=1e-6)
    assert ground.problem == whole.problem


def test_an_hour_in_flight_is_not_kept(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A long flight keeps the ground seconds and a border of the flight, not the flight."""
    monkeypatch.setattr(logs, "FLIGHT_S", 300.0)
    truths = sensors(42, 3)
    path = tmp_path / "long.ulg"
    write_ulog_flight(path, fly(truths, 42), [true_in_force(t) for t in truths])
    samples = ground_samples(path, 1, 2.0)
    ground_s = 2 * (logs.GROUND_S - 2.0 + 1.0)  # each side: the ground less the margin, and a 1 s border
    assert len(samples.t_ns) <= (ground_s + 2.0) * logs.RATE_HZ
    assert samples.samples_read is not None and samples.samples_read > 300 * logs.RATE_HZ


def test_each_instance_keeps_its_first_row_even_in_flight(flight_ulog: Path) -> None:
    """Its device ID: an instance whose rows all fall in a flight still says which IMU it is."""
    from accel_calibration.bag.ulog_pass import log_pass

    passed = log_pass(flight_ulog, 1e5)  # a margin that takes the whole log for the flight's
    assert passed.kept is not None
    accels = sorted(n for name, n in passed.kept if name == "sensor_accel")
    assert accels == [0, 1, 2]
    assert all(len(passed.kept[("sensor_accel", n)].columns["device_id"]) == 1 for n in accels)
    assert all(passed.kept[("sensor_accel", n)].columns["device_id"][0] > 0 for n in accels)
    assert all(passed.subscriptions[("sensor_accel", n)].rows > 1000 for n in accels)


def test_a_cut_log_read_for_its_ground_is_refused_in_one_line(flight_ulog: Path, tmp_path: Path) -> None:
    cut = tmp_path / "cut.ulg"
    data = flight_ulog.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(UlogError, match="truncated ULog") as raised:
        ground_samples(cut, 0, 2.0)
    assert "\n" not in str(raised.value)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_a_damaged_log_read_for_its_ground_gives_samples_or_one_line(flight_ulog: Path, tmp_path_factory,
                                                                    data: st.DataObject) -> None:
    """Bytes of the data section overwritten (a record's size, a msg_id, a subscription's name): the ground read
    and the fleet's task give samples or one UlogError line, never another exception."""
    from accel_calibration.cli.fleet import calibrate_recording
    from accel_calibration.core.errors import AccelCalibrationError

    raw = bytearray(flight_ulog.read_bytes())
    for _ in range(data.draw(st.integers(1, 4))):
        at = data.draw(st.integers(len(raw) // 20, len(raw) - 1))
        raw[at:at + 2] = data.draw(st.binary(min_size=2, max_size=2))
    path = tmp_path_factory.mktemp("damaged") / "flight.ulg"
    path.write_bytes(bytes(raw))
    try:
        ground_samples(path, data.draw(st.sampled_from([None, 0, 2])), 2.0)
    except AccelCalibrationError as error:
        assert "\n" not in str(error)
    outcome = calibrate_recording(str(path))  # the task boundary: rows with reasons, never a raise
    for row in (outcome, *outcome.others):
        assert row.reason is None or "\n" not in row.reason


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_a_damaged_dataflash_log_through_the_fleets_pass_gives_rows_with_reasons(tmp_path_factory,
                                                                                 data: st.DataObject) -> None:
    """The same for an ArduPilot log read by the fleet's pass (bag/dataflash_pass.py)."""
    from accel_calibration.cli.fleet import calibrate_recording

    from helpers.flight_logs import write_dataflash_flight

    folder = tmp_path_factory.mktemp("damaged_bin")
    truths = sensors(43, 3)
    write_dataflash_flight(folder / "whole.bin", fly(truths, 43), [true_in_force(t) for t in truths])
    raw = bytearray((folder / "whole.bin").read_bytes())
    for _ in range(data.draw(st.integers(1, 4))):
        at = data.draw(st.integers(0, len(raw) - 1))
        raw[at:at + 2] = data.draw(st.binary(min_size=2, max_size=2))
    path = folder / "flight.bin"
    path.write_bytes(bytes(raw))
    outcome = calibrate_recording(str(path))
    for row in (outcome, *outcome.others):
        assert row.reason is None or "\n" not in row.reason


@pytest.mark.parametrize("instance", [None, 0, 1])
def test_a_log_that_never_flew_is_streamed_to_the_poses_and_calibration_of_the_whole_read(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, instance: int | None) -> None:
    """A turned calibration session logged with no flight state: all of it is ground, so the ground read gives
    its samples a block at a time (small blocks here: a gyro interpolated across their edges), to the same poses
    and calibration as the whole read, and never holds the log whole."""
    import accel_calibration.bag.ulog_stream as ulog_stream
    from accel_calibration.bag.recording import StreamedLog, open_recording

    from helpers.autopilot_logs import simulate, write_px4_log

    path = tmp_path / "session.ulg"
    write_px4_log(path, simulate(44))
    monkeypatch.setattr(ulog_stream, "BLOCK_BYTES", 1 << 15)
    streamed = open_recording(path, instance=instance, ground_margin_s=2.0)
    assert isinstance(streamed, StreamedLog) and len(streamed.t_ns) < 2000  # a block's, not the log's
    whole = replay_bag(path, ReplaySettings(instance=instance))
    ground = replay_bag(path, ReplaySettings(instance=instance, ground_only=True))
    assert ground.source.messages == whole.source.messages
    assert ground.source.duration_s == pytest.approx(whole.source.duration_s)
    assert len(whole.poses) >= 12 and len(ground.poses) == len(whole.poses)
    for a, b in zip(whole.poses, ground.poses, strict=True):
        assert (a.start_ns, a.end_ns, a.samples) == (b.start_ns, b.end_ns, b.samples)
        np.testing.assert_allclose(b.accel_mps2, a.accel_mps2, rtol=0, atol=1e-9)
        np.testing.assert_allclose(b.gyro_radps, a.gyro_radps, rtol=0, atol=1e-9)
    assert whole.calibration is not None and ground.calibration is not None
    np.testing.assert_allclose(ground.calibration.matrix, whole.calibration.matrix, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ground.calibration.bias, whole.calibration.bias, rtol=0, atol=1e-9)
    said = ("stream", "fitted_to", "sensor_id", "vehicle", "imu_instances", "accel_device_id", "gyro_device_id",
            "temperature_stream", "format")
    assert [getattr(ground.source.recording, k) for k in said] == [getattr(whole.source.recording, k) for k in said]


@pytest.mark.parametrize("instance", [0, 1])
def test_a_dataflash_log_that_never_flew_is_streamed_to_the_whole_reads_calibration(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, instance: int) -> None:
    import accel_calibration.bag.dataflash_records as records
    from accel_calibration.bag.recording import StreamedLog, open_recording

    from helpers.autopilot_logs import simulate, write_ardupilot_log

    path = tmp_path / "session.bin"
    write_ardupilot_log(path, simulate(45), devices=(1310988, 1442060))
    monkeypatch.setattr(records, "BLOCK_BYTES", 1 << 14)
    streamed = open_recording(path, instance=instance, ground_margin_s=2.0)
    assert isinstance(streamed, StreamedLog) and len(streamed.t_ns) < 1000
    whole = replay_bag(path, ReplaySettings(instance=instance))
    ground = replay_bag(path, ReplaySettings(instance=instance, ground_only=True))
    assert ground.source.messages == whole.source.messages
    assert len(whole.poses) >= 12 and len(ground.poses) == len(whole.poses)
    for a, b in zip(whole.poses, ground.poses, strict=True):
        np.testing.assert_allclose(b.accel_mps2, a.accel_mps2, rtol=0, atol=1e-9)
    assert whole.calibration is not None and ground.calibration is not None
    np.testing.assert_allclose(ground.calibration.matrix, whole.calibration.matrix, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ground.calibration.bias, whole.calibration.bias, rtol=0, atol=1e-9)
    said = ("stream", "fitted_to", "sensor_id", "imu_instances", "accel_device_id", "gyro_device_id",
            "temperature_stream", "format")
    assert [getattr(ground.source.recording, k) for k in said] == [getattr(whole.source.recording, k) for k in said]


@pytest.mark.parametrize("suffix", ["ulg", "bin"])
@pytest.mark.parametrize("instance", [None, 1])
def test_a_ground_too_long_to_keep_is_streamed_to_the_same_poses(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                  suffix: str, instance: int | None) -> None:
    """A flight log whose ground outgrows what a pass keeps (KEEP_BYTES, tiny here: an hour on the ground and a
    minute of flight) is streamed to each replay, its flight's inside left out: the poses of the whole read."""
    import accel_calibration.bag.dataflash_pass as dataflash_pass
    import accel_calibration.bag.ulog_pass as ulog_pass
    from accel_calibration.bag.recording import StreamedLog, open_recording

    from helpers.flight_logs import write_dataflash_flight

    monkeypatch.setattr(ulog_pass, "KEEP_BYTES", 1000)
    monkeypatch.setattr(dataflash_pass, "KEEP_BYTES", 1000)
    truths = sensors(46, 3)
    path = tmp_path / f"flight.{suffix}"
    write = write_ulog_flight if suffix == "ulg" else write_dataflash_flight
    write(path, fly(truths, 46), [true_in_force(t) for t in truths])
    assert isinstance(open_recording(path, instance=instance, ground_margin_s=2.0), StreamedLog)
    whole = replay_bag(path, ReplaySettings(instance=instance))
    ground = replay_bag(path, ReplaySettings(instance=instance, ground_only=True))
    assert ground.source.messages == whole.source.messages
    assert ground.source.duration_s == pytest.approx(whole.source.duration_s)
    assert len(whole.poses) >= 1 and len(ground.poses) == len(whole.poses)
    for a, b in zip(whole.poses, ground.poses, strict=True):
        assert (a.start_ns, a.end_ns, a.samples) == (b.start_ns, b.end_ns, b.samples)
        np.testing.assert_allclose(b.accel_mps2, a.accel_mps2, rtol=0, atol=1e-9)
    assert ground.problem == whole.problem
