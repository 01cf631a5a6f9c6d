"""Replay streams a bag's storage (mcap chunk by chunk, sqlite3 a fetch at a time) into the session in
parts, so a worker's memory is bounded by a part, not the bag: the result is bit for bit the replay of
the recording read whole, whatever the group and part sizes; where streaming cannot give what the whole
read gives (log times going back across chunks, another definition) the bag is read whole instead."""
from __future__ import annotations

import shutil

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from accel_calibration.bag import recording as recording_module
from accel_calibration.bag.recording import BagStream, Recording, open_recording
from accel_calibration.bag.replay import ReplaySettings, replay_bag, replay_recording
from msg_tools.bag_writer import write_session_bag
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

START_NS = 1_700_000_000 * 10**9


@pytest.fixture(scope="module")
def session():
    rng = np.random.default_rng(5)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    return SyntheticImu(errors, spread_orientations(16, rng), dwell_s=2.0, move_s=0.8, rate_hz=200.0, seed=5,
                        temperature_degc=lambda t: 20.0 + 0.1 * t).samples()


@pytest.fixture(scope="module")
def bags(tmp_path_factory, session):
    folder = tmp_path_factory.mktemp("stream")
    made = {}
    for name, storage, compression in (("sqlite3", "sqlite3", ""), ("mcap", "mcap", ""), ("mcap-zstd", "mcap", "zstd")):
        made[name] = folder / name
        write_session_bag(made[name], session, start_ns=START_NS, storage=storage, chunk_compression=compression,
                          shuffle_seed=3)  # neighbours swapped in the file, as recorders do
    return made


def same_replay(streamed, whole):
    assert [(p.start_ns, p.end_ns, p.samples, *p.accel_mps2.tolist(), p.temperature_degc) for p in streamed.poses] \
        == [(p.start_ns, p.end_ns, p.samples, *p.accel_mps2.tolist(), p.temperature_degc) for p in whole.poses]
    assert streamed.counts == whole.counts
    a, b = streamed.source, whole.source
    assert (a.messages, a.duration_s, a.frame_id, a.start_ns) == (b.messages, b.duration_s, b.frame_id, b.start_ns)
    assert streamed.problem == whole.problem
    if whole.calibration is not None:
        np.testing.assert_array_equal(streamed.calibration.bias, whole.calibration.bias)
        np.testing.assert_array_equal(streamed.calibration.matrix, whole.calibration.matrix)


@pytest.mark.parametrize("kind", ["sqlite3", "mcap", "mcap-zstd"])
@pytest.mark.parametrize("group, part", [(1 << 16, 1 << 17), (257, 1000), (4000, 333)])
def test_a_streamed_bag_replays_as_read_whole(bags, kind, group, part, monkeypatch):
    monkeypatch.setattr(recording_module, "STREAM_GROUP_MESSAGES", group)
    in_parts = ReplaySettings(part_rows=part)
    streamed = replay_bag(bags[kind], in_parts)
    assert isinstance(streamed.source.recording, BagStream)  # it was streamed, not read whole
    whole = replay_recording(open_recording(bags[kind]), in_parts)
    assert isinstance(whole.source.recording, Recording)
    same_replay(streamed, whole)
    assert len(streamed.poses) >= 12 and streamed.calibration is not None, streamed.problem
    assert streamed.source.temperature_topic == "/imu/temperature"
    assert all(p.temperature_degc is not None for p in streamed.poses)


def test_log_times_going_back_across_chunks_read_whole(tmp_path, bags, monkeypatch):
    """A message logged before the previous group's latest: the whole read sorts the file by log time, so
    streaming would give another order; replay notices and reads it whole (the same result as whole)."""
    monkeypatch.setattr(recording_module, "STREAM_GROUP_MESSAGES", 500)
    bag = tmp_path / "late"
    store = get_typestore(Stores.ROS2_JAZZY)
    with AnyReader([bags["mcap"]], default_typestore=store) as reader, \
            Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        out = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=store) for c in reader.connections}
        messages = list(reader.messages())
        for k, (connection, timestamp, raw) in enumerate(messages):
            if k == len(messages) - 1:
                timestamp -= 30 * 10**9  # the last message logged 30 s early: its place is chunks back
            writer.write(out[connection.id], timestamp, raw)
    streamed = replay_bag(bag)
    assert isinstance(streamed.source.recording, Recording)  # read whole
    same_replay(streamed, replay_recording(open_recording(bag)))


def test_a_damaged_bag_streamed_is_the_same_one_line(tmp_path, bags):
    """Cut short mid-file: streaming stops, the whole read says what is wrong, as before."""
    bag = tmp_path / "cut"
    shutil.copytree(bags["mcap-zstd"], bag)
    storage = next(bag.glob("*.mcap"))
    data = storage.read_bytes()
    storage.write_bytes(data[:len(data) // 2])
    from accel_calibration.bag.replay import ReplayError

    with pytest.raises(ReplayError) as error:
        replay_bag(bag)
    assert len(str(error.value).splitlines()) == 1 and str(bag) in str(error.value)


def raw_messages(path):
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        return [(c.topic, timestamp, bytes(raw)) for c, timestamp, raw in reader.messages()]


def node_corrections(calibration, temperature_readings, t_ns, accel, gyro):
    """What the node publishes, message by message in plain floats: each temperature reading filtered as it
    comes (stamp order), the correction rebuilt when the correction temperature moves (core.correction's
    rule), each Imu corrected with the Correction in force at its stamp."""
    from accel_calibration.core.correction import Correction, correction_temperatures
    from accel_calibration.core.stream.temperature_filter import TemperatureFilter

    stamps, values = temperature_readings
    order = np.argsort(stamps, kind="stable")
    stamps, values = np.asarray(stamps)[order].tolist(), np.asarray(values)[order].tolist()
    live_filter = TemperatureFilter()
    held, k = None, 0
    correction = Correction.build(calibration, None)
    out_a, out_g = np.empty_like(accel), np.empty_like(gyro)
    for i, t in enumerate(np.asarray(t_ns).tolist()):
        while k < len(stamps) and stamps[k] <= t:
            _, filtered = live_filter.take([stamps[k]], [values[k]])
            k += 1
            moved = float(correction_temperatures(filtered[-1:], held)[0])
            if moved != held:
                held, correction = moved, Correction.build(calibration, moved)
        out_a[i] = correction.apply(*(float(v) for v in accel[i]))
        out_g[i] = correction.apply_gyro(*(float(v) for v in gyro[i]))
    return out_a, out_g


@pytest.mark.parametrize("name", ["sqlite3", "mcap-zstd"])
def test_a_corrected_copy_is_written_a_group_at_a_time_with_the_whole_recordings_numbers(bags, tmp_path, name):
    """The copy is read, corrected and written a group at a time (memory: a group, not the bag): with
    groups of 7 IMU messages, or of 2 kB of any topic, it is the copy made in one group, byte for byte (the
    correction is elementwise arithmetic, no BLAS: the same bits for any group size on any CPU), and each
    sample is what the node publishes for it: the Correction in force at its stamp (a temperature model that
    moves 10 mg per degC over the recording's 20-25 degC ramp), the gyro bias taken off: bit for bit the
    node's per-message floats (the correction temperature is rounded to 1 mdegC before its 0.05 degC step,
    so the filter's last bits, which differ between one reading at a time and all at once, never decide)."""
    from accel_calibration.bag.corrected_copy import write_corrected_bag
    from accel_calibration.core.temperature_models import TemperatureModel

    replay = replay_bag(bags[name])  # streamed: no whole read behind the copy
    assert isinstance(replay.source.recording, BagStream) and replay.calibration is not None
    drift = TemperatureModel("polynomial", 22.0, (18.0, 30.0), bias_coefficients=[[0.1, -0.1, 0.05]])
    calibration = replay.calibration.replace(temperature=drift)
    assert calibration.gyro_bias_radps is not None
    copies = {}
    for label, groups in (("one", dict(group_messages=1 << 40, group_bytes=1 << 60)),
                          ("by count", dict(group_messages=7)), ("by bytes", dict(group_bytes=2000))):
        copies[label] = tmp_path / label.replace(" ", "_")
        written = write_corrected_bag(replay, calibration, copies[label], **groups)
        assert written == len(raw_messages(bags[name]))
    one = raw_messages(copies["one"])
    assert raw_messages(copies["by count"]) == one and raw_messages(copies["by bytes"]) == one

    whole = open_recording(bags[name], through_rosbags=True)  # rosbags' order: the copy's order
    assert np.ptp(whole.temperature[1]) > 3.0
    expected_a, expected_g = node_corrections(calibration, whole.temperature, whole.t_ns, whole.accel_mps2,
                                              whole.gyro_radps)
    corrected = open_recording(copies["by count"], through_rosbags=True)
    np.testing.assert_array_equal(corrected.accel_mps2, expected_a)
    np.testing.assert_array_equal(corrected.gyro_radps, expected_g)
    np.testing.assert_array_equal(corrected.t_ns, whole.t_ns)
    # Against the copy without the drift: it moved each sample by the model's bias at its temperature.
    plain, _ = node_corrections(replay.calibration, whole.temperature, whole.t_ns, whole.accel_mps2, whole.gyro_radps)
    assert np.abs(expected_a - plain).max() > 0.05
