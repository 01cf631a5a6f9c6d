"""Hostile and damaged bags: truncated or corrupted storage (sqlite3; mcap plain, zstd and lz4 chunks),
a metadata.yaml that lies about the types, unsafe YAML, FIFOs, and recordings whose Imu definition is not
sensor_msgs/msg/Imu's. One line naming the bag, never a traceback; another definition is read through
its own (same samples as the standard recording), never at the standard's offsets. Then hypothesis:
mutated bytes of small valid bags never give a traceback and never change an input."""
from __future__ import annotations

import os
import shutil
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from accel_calibration.bag.bag_io import IMU, TEMPERATURE
from accel_calibration.bag.replay import replay_bag
from msg_tools.bag_writer import write_session_bag
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

from helpers.one_line import assert_at_most_one_line, assert_one_error_line, run_main

START_NS = 1_700_000_000 * 10**9
KINDS = {"sqlite3": ("sqlite3", ""), "mcap": ("mcap", ""), "mcap-zstd": ("mcap", "zstd"), "mcap-lz4": ("mcap", "lz4")}


def samples(seed=1, poses=14):
    rng = np.random.default_rng(seed)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    return SyntheticImu(errors, spread_orientations(poses, rng), dwell_s=2.0, move_s=0.8, rate_hz=100.0,
                        seed=seed).samples()


@pytest.fixture(scope="module")
def session():
    return samples()


@pytest.fixture(scope="module")
def bags(tmp_path_factory, session):
    """One valid bag per storage kind, written once; tests copy them before damaging anything."""
    folder = tmp_path_factory.mktemp("valid")
    made = {}
    for name, (storage, compression) in KINDS.items():
        made[name] = folder / name
        write_session_bag(made[name], session, start_ns=START_NS, storage=storage, chunk_compression=compression)
    return made


def copy(bag, destination):
    shutil.copytree(bag, destination)
    return destination


def storage_file(bag):
    return next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))


def contents(bag):
    return {p.name: p.read_bytes() for p in sorted(Path(bag).iterdir())}


# ------------------------------------------------------------------------------------------ damaged storage

@pytest.mark.parametrize("kind", sorted(KINDS))
@pytest.mark.parametrize("damage", ["truncate-half", "truncate-tail", "zero-middle", "no-footer"])
def test_damaged_storage_is_one_line_naming_the_bag(tmp_path, bags, kind, damage):
    bag = copy(bags[kind], tmp_path / f"damaged-{kind}")
    storage = storage_file(bag)
    data = bytearray(storage.read_bytes())
    if damage == "truncate-half":
        data = data[: len(data) // 2]
    elif damage == "truncate-tail":
        data = data[: len(data) - 100]
    elif damage == "zero-middle":
        middle = len(data) // 2
        data[middle:middle + 4096] = bytes(4096)
    else:
        data = data[: len(data) - 37]  # the mcap footer and closing magic (sqlite3: its tail)
    storage.write_bytes(bytes(data))
    before = contents(bag)
    for extra in ([], ["--corrected-bag", tmp_path / "copy"]):  # the fast reader, then rosbags' for a copy
        code, err = run_main(["replay", bag, "-o", tmp_path / "cal.yaml", *extra])
        if code == 0:  # damage that hit only data values (the zeroed block): a calibration or a refusal
            assert err == ""
            continue
        assert_one_error_line(code, err, str(bag))
    assert contents(bag) == before


def test_truncated_bags_are_refused_not_read_in_part(tmp_path, bags):
    for kind in sorted(KINDS):
        bag = copy(bags[kind], tmp_path / kind)
        storage = storage_file(bag)
        storage.write_bytes(storage.read_bytes()[: storage.stat().st_size // 2])
        assert_one_error_line(*run_main(["replay", bag]), str(bag))


# ------------------------------------------------------------------------------------------------ metadata

def edit_metadata(bag, edit):
    path = bag / "metadata.yaml"
    document = yaml.safe_load(path.read_text())
    edit(document["rosbag2_bagfile_information"]["topics_with_message_count"])
    path.write_text(yaml.safe_dump(document))


def swap_types(topics):
    a, b = topics[0]["topic_metadata"], topics[1]["topic_metadata"]
    a["type"], b["type"] = b["type"], a["type"]
    a["type_description_hash"], b["type_description_hash"] = b["type_description_hash"], a["type_description_hash"]


def other_type(topics):
    imu = next(t for t in topics if t["topic_metadata"]["type"] == IMU)["topic_metadata"]
    imu["type"] = "sensor_msgs/msg/MagneticField"


def other_hash(topics):
    imu = next(t for t in topics if t["topic_metadata"]["type"] == IMU)["topic_metadata"]
    imu["type_description_hash"] = "RIHS01_" + "0" * 64


@pytest.mark.parametrize("kind", ["sqlite3", "mcap-zstd"])
@pytest.mark.parametrize("edit, message", [
    (swap_types, "the metadata does not belong to this recording"),
    (other_type, "no sensor_msgs/msg/Imu topic"),
    (other_hash, "hash mismatch"),
])
def test_metadata_that_lies_about_types_is_refused(tmp_path, bags, kind, edit, message):
    bag = copy(bags[kind], tmp_path / "lying")
    edit_metadata(bag, edit)
    for extra in ([], ["--corrected-bag", tmp_path / "copy"]):
        assert_one_error_line(*run_main(["replay", bag, *extra]), str(bag), message)
    assert not (tmp_path / "copy").exists()


@pytest.mark.parametrize("text, message", [
    ("rosbag2_bagfile_information: " + "[" * 100_000 + "]" * 100_000 + "\n", "nested deeper"),
    ("a: &a [x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a]\n"
     "rosbag2_bagfile_information: [*b, *b, *b, *b, *b, *b, *b, *b]\n", "aliases"),
])
def test_unsafe_metadata_yaml_is_one_line(tmp_path, bags, text, message):
    bag = copy(bags["sqlite3"], tmp_path / "unsafe")
    (bag / "metadata.yaml").write_text(text)
    assert_one_error_line(*run_main(["replay", bag]), "metadata.yaml", message)


@pytest.mark.parametrize("name", ["metadata.yaml", "fifo.db3"])
def test_a_fifo_in_a_bag_is_refused_without_opening_it(tmp_path, bags, name):
    bag = copy(bags["sqlite3"], tmp_path / "piped")
    fifo = bag / name
    if fifo.exists():
        fifo.unlink()
    os.mkfifo(fifo)
    # A writer that opens the FIFO once: a reader that (wrongly) opened it sees EOF instead of hanging.
    opener = threading.Thread(target=lambda: os.close(os.open(fifo, os.O_WRONLY)), daemon=True)
    opener.start()
    try:
        assert_one_error_line(*run_main(["replay", bag]), "FIFO")
        assert opener.is_alive()  # nobody opened it
    finally:
        fd = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
        opener.join()
        os.close(fd)


# --------------------------------------------------------------------------- another Imu definition

SWAPPED_IMU = """std_msgs/Header header
geometry_msgs/Vector3 linear_acceleration
float64[9] linear_acceleration_covariance
geometry_msgs/Vector3 angular_velocity
float64[9] angular_velocity_covariance
geometry_msgs/Quaternion orientation
float64[9] orientation_covariance
"""
NO_ACCEL_IMU = """std_msgs/Header header
geometry_msgs/Quaternion orientation
float64[9] orientation_covariance
geometry_msgs/Vector3 angular_velocity
float64[9] angular_velocity_covariance
geometry_msgs/Vector3 specific_force
float64[9] linear_acceleration_covariance
"""


def store_with_imu(definition):
    """A typestore holding Jazzy's types but `definition` as sensor_msgs/msg/Imu, as a recording from a
    stack with its own (or an older, or a vendor's) Imu would carry."""
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    store = get_typestore(Stores.EMPTY)
    store.register({name: jazzy.fielddefs[name] for name in (
        "std_msgs/msg/Header", "builtin_interfaces/msg/Time", "geometry_msgs/msg/Vector3",
        "geometry_msgs/msg/Quaternion", TEMPERATURE)})
    store.register(get_types_from_msg(definition, IMU))
    return store


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_another_imu_definition_is_read_through_its_own_never_at_the_standard_offsets(tmp_path, bags, session,
                                                                                       storage):
    """Same size as the standard Imu, fields in another order: decoded at the standard offsets, gyro would
    be read as acceleration. Read through its recorded definition it gives exactly the standard bag's
    samples, poses and calibration."""
    bag = tmp_path / "swapped"
    write_session_bag(bag, session, start_ns=START_NS, storage=storage, typestore=store_with_imu(SWAPPED_IMU))
    from accel_calibration.bag.recording import open_recording

    standard_bag = bags["sqlite3" if storage == "sqlite3" else "mcap"]
    standard, samples = replay_bag(standard_bag), open_recording(standard_bag)  # (replay streams it)
    for through_rosbags in (False, True):
        other = replay_bag(bag, through_rosbags=through_rosbags)  # not streamed: another definition is read whole
        np.testing.assert_array_equal(other.source.recording.accel_mps2, samples.accel_mps2)
        np.testing.assert_array_equal(other.source.recording.gyro_radps, samples.gyro_radps)
        assert len(other.poses) == len(standard.poses)
        if standard.calibration is not None:
            np.testing.assert_array_equal(other.calibration.bias, standard.calibration.bias)
    np.testing.assert_allclose(samples.accel_mps2, session.accel_raw, rtol=0, atol=0)


def test_a_corrected_copy_of_another_definition_keeps_it(tmp_path, session):
    bag = tmp_path / "swapped"
    store = store_with_imu(SWAPPED_IMU)
    write_session_bag(bag, session, start_ns=START_NS, storage="mcap", typestore=store)
    replay = replay_bag(bag, through_rosbags=True)
    if replay.calibration is None:
        pytest.skip(f"no calibration from this session today: {replay.problem}")
    from accel_calibration.bag.corrected_copy import write_corrected_bag

    write_corrected_bag(replay, replay.calibration, tmp_path / "corrected")
    again = replay_bag(tmp_path / "corrected", through_rosbags=True).source.recording
    np.testing.assert_allclose(again.accel_mps2, replay.calibration.apply(session.accel_raw), atol=1e-12)
    # The gyro corrected too, as the node corrects it (core.correction's one correction; BLAS: 1e-15).
    np.testing.assert_allclose(again.gyro_radps, replay.calibration.apply_gyro(session.gyro_raw),
                               rtol=0, atol=1e-15)


def test_an_imu_definition_without_linear_acceleration_is_refused(tmp_path, session):
    store = store_with_imu(NO_ACCEL_IMU)
    from rosbags.rosbag2 import Writer

    types = store.types
    bag = tmp_path / "no_accel"
    with Writer(bag, version=9) as writer:
        connection = writer.add_connection("/imu/data_raw", IMU, typestore=store)
        for i in range(50):
            header = types["std_msgs/msg/Header"](
                stamp=types["builtin_interfaces/msg/Time"](sec=1_700_000_000 + i, nanosec=0), frame_id="imu")
            vector = types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=9.8)
            msg = types[IMU](header=header, orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0,
                                                                                              w=1.0),
                             orientation_covariance=np.zeros(9), angular_velocity=vector,
                             angular_velocity_covariance=np.zeros(9), specific_force=vector,
                             linear_acceleration_covariance=np.zeros(9))
            writer.write(connection, START_NS + i, store.serialize_cdr(msg, IMU))
    assert_one_error_line(*run_main(["replay", bag]), str(bag), "lacks what an IMU message has")


# ---------------------------------------------------------------------------------------- hypothesis

mutations = st.lists(st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.integers(0, 255)), min_size=1, max_size=8)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                   HealthCheck.too_slow])
@given(kind=st.sampled_from(sorted(KINDS)), target=st.sampled_from(["storage", "metadata.yaml"]),
       changes=mutations, cut=st.one_of(st.none(), st.floats(0.0, 1.0)), copy_out=st.booleans())
def test_mutated_bags_never_traceback_and_are_never_changed(tmp_path_factory, bags, kind, target, changes, cut,
                                                             copy_out):
    folder = tmp_path_factory.mktemp("mutated")
    bag = copy(bags[kind], folder / "bag")
    victim = storage_file(bag) if target == "storage" else bag / "metadata.yaml"
    data = bytearray(victim.read_bytes())
    for where, value in changes:
        data[int(where * len(data))] = value
    if cut is not None:
        data = data[: int(cut * len(data))]
    victim.write_bytes(bytes(data))
    before = contents(bag)
    extra = ["--corrected-bag", folder / "copy"] if copy_out else []
    code, err = run_main(["replay", bag, "-o", folder / "cal.yaml", "--report", folder / "r.png", *extra])
    assert_at_most_one_line(code, err)
    assert contents(bag) == before


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_a_chunk_that_decompresses_past_its_declared_size_is_never_handed_to_another_reader(tmp_path, capsys,
                                                                                            compression):
    """Found by the docs audit: our mcap reader stops at a chunk's declared size, but then fell back to
    rosbags' reader, which decompresses the chunk whole before it refuses it: a chunk declaring 1 KB that
    inflates to gigabytes would be inflated. The damage is said by our reader, at the declared size."""
    import struct

    import rosbags.rosbag2

    from accel_calibration.cli.main import main

    samples = SyntheticImu(SensorErrors(noise_mps2=0.02), spread_orientations(6, np.random.default_rng(5)),
                           dwell_s=1.0, move_s=0.5, rate_hz=100.0, seed=5).samples()
    bag = tmp_path / "bag"
    write_session_bag(bag, samples, start_ns=START_NS, storage="mcap", chunk_compression=compression)
    (mcap,) = bag.glob("*.mcap")
    data = bytearray(mcap.read_bytes())
    offset = 8
    while offset < len(data) - 8:  # the first chunk's uncompressed size, halved (its crc zeroed: unchecked)
        opcode, length = data[offset], struct.unpack_from("<Q", data, offset + 1)[0]
        if opcode == 0x06:
            (size,) = struct.unpack_from("<Q", data, offset + 9 + 16)
            struct.pack_into("<QI", data, offset + 9 + 16, size // 2, 0)
            break
        offset += 9 + length
    mcap.write_bytes(bytes(data))
    opened = []
    real_reader = rosbags.rosbag2.Reader

    class Watched(real_reader):  # type: ignore[misc,valid-type]
        def __init__(self, *args, **kwargs):
            opened.append(args)
            super().__init__(*args, **kwargs)

    rosbags.rosbag2.Reader = Watched
    try:
        code = main(["replay", str(bag), "-o", str(tmp_path / "cal.yaml")])
    finally:
        rosbags.rosbag2.Reader = real_reader
    err = capsys.readouterr().err
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert "decompresses to" in err and "past its declared size" in err, err
    assert not opened and not (tmp_path / "cal.yaml").exists()
