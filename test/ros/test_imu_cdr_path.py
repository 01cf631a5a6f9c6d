"""The node's Imu path over serialised bytes (msg_tools/imu_cdr.py, `ros/imu_path.py`): for any message it
publishes the bytes that serialising its message path's output gives, and pushes the same raw sample; a
message in another layout (big-endian) goes through the message path, a damaged one is one logged error.
A real rclpy node in this process, its callbacks called directly, what it publishes captured."""
from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Imu

from accel_calibration.io.calibration_file import save_calibration
from msg_tools.conversions import make_temperature
from msg_tools.imu_cdr import FRAME_AT, STAMP, VECTOR, imu_offsets

from helpers.sensors import calibration_with_drift

START_NS = 1_700_000_000 * 10**9
ORIENTATION_BEFORE_GYRO = 32 + 72  # the orientation and its covariance


@pytest.fixture(scope="module")
def node(ros, tmp_path_factory):
    from accel_calibration.ros.node import CalibrationNode

    path = tmp_path_factory.mktemp("imu_cdr") / "cal.yaml"
    save_calibration(calibration_with_drift(), path)
    node = CalibrationNode(parameter_overrides=[Parameter("calibration_file", value=str(path))])
    node._on_temperature(make_temperature(START_NS, 27.5))  # the drift takes part
    published: list[object] = []
    pushed: list[tuple[object, ...]] = []
    node._publisher.publish = published.append
    buffer_imu = node._stream.buffer_imu
    node._stream.buffer_imu = lambda *sample: (pushed.append(sample), buffer_imu(*sample))
    node.captured = published, pushed
    yield node
    node.close()
    node.destroy_node()


def sent_bytes(published: object) -> bytes:
    """What a subscriber reads of a published Imu: its serialised bytes, the alignment padding between the
    frame_id's NUL and the first double zeroed (rclpy's serialiser leaves there whatever its buffer's memory
    held: test_the_alignment_padding_is_not_part_of_what_is_compared)."""
    raw = bytearray(published if isinstance(published, bytes) else serialize_message(published))
    offsets = imu_offsets(bytes(raw))
    if offsets is not None:
        start, end = offsets.frame_end + 1, offsets.gyro - ORIENTATION_BEFORE_GYRO
        raw[start:end] = bytes(end - start)
    return bytes(raw)


def bits(sample: tuple[object, ...]) -> bytes:
    """A pushed sample, NaN payloads and signs included."""
    return struct.pack("<q6d", *sample)


values = st.floats(allow_nan=True, allow_infinity=True, width=64)
finite = st.floats(-1e3, 1e3)
covariances = st.one_of(st.just([-1.0] + [0.0] * 8), st.just([0.0] * 9),
                        st.lists(st.floats(0, 1e-2), min_size=9, max_size=9))


@st.composite
def imus(draw):
    msg = Imu()
    msg.header.frame_id = draw(st.sampled_from(["imu_link", "", "imu", "a" * 33, "bâse_ïmu"]) | st.text(max_size=20))
    stamp = START_NS + draw(st.integers(0, 10**12))
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
    vectors = st.tuples(*[st.one_of(finite, values)] * 3)
    msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = draw(vectors)
    msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = draw(vectors)
    msg.orientation_covariance[0] = -1.0
    msg.linear_acceleration_covariance = np.array(draw(covariances))
    msg.angular_velocity_covariance = np.array(draw(covariances))
    return msg


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(msg=imus(), enabled=st.booleans(), noise=st.sampled_from([None, (4e-4, 1e-5)]))
def test_the_bytes_path_publishes_what_the_message_path_would(node, msg, enabled, noise):
    published, pushed = node.captured
    node._stream.enabled = enabled
    node._stream.set_noise(*(noise or (None, None)))
    raw = bytes(serialize_message(msg))
    sent = deserialize_message(raw, Imu)  # a frame_id is a C string: a NUL ends it
    offsets = imu_offsets(raw)
    assert offsets is not None
    assert raw[16:offsets.frame_end].decode() == sent.header.frame_id
    assert VECTOR.unpack_from(raw, offsets.accel)[2] == msg.linear_acceleration.z or math.isnan(
        msg.linear_acceleration.z)
    assert STAMP.unpack_from(raw, 4) == (msg.header.stamp.sec, msg.header.stamp.nanosec)

    node._imu.take(sent)
    node._imu.take_cdr(raw)
    assert node._stream.frame_id == sent.header.frame_id
    assert sent_bytes(published[-1]) == sent_bytes(published[-2])
    assert bits(pushed[-1]) == bits(pushed[-2])
    corrected = enabled and all(map(math.isfinite, (msg.linear_acceleration.x, msg.linear_acceleration.y,
                                                    msg.linear_acceleration.z)))
    assert (sent_bytes(published[-1]) != sent_bytes(raw)) == corrected  # else passed through untouched


def test_a_big_endian_message_goes_through_the_message_path(node):
    from rosbags.typesys import Stores, get_typestore

    published, _ = node.captured
    node._stream.enabled = True
    msg = Imu()
    msg.header.frame_id = "imu_link"
    msg.linear_acceleration.z = 9.8
    msg.angular_velocity.x = 0.3
    raw = bytes(serialize_message(msg))
    store = get_typestore(Stores.ROS2_JAZZY)
    big = bytes(store.serialize_cdr(store.deserialize_cdr(raw, "sensor_msgs/msg/Imu"), "sensor_msgs/msg/Imu",
                                    little_endian=False))
    assert big[1] == 0 and imu_offsets(big) is None
    node._imu.take_cdr(raw)
    node._imu.take_cdr(big)
    assert isinstance(published[-2], bytes) and isinstance(published[-1], Imu)
    assert sent_bytes(published[-1]) == sent_bytes(published[-2])
    assert published[-1].linear_acceleration.z != 9.8  # corrected
    # The frame_id a big-endian message brings is the stream's; the bytes path then notices its own again.
    msg.header.frame_id = "other_link"
    node._imu.take_cdr(bytes(store.serialize_cdr(store.deserialize_cdr(bytes(serialize_message(msg)),
                                                                      "sensor_msgs/msg/Imu"),
                                               "sensor_msgs/msg/Imu", little_endian=False)))
    assert node._stream.frame_id == "other_link"
    node._imu.take_cdr(raw)
    assert node._stream.frame_id == "imu_link"


@pytest.mark.parametrize("damaged", [b"", b"\x00\x01\x00\x00", b"\x00\x01\x00\x00" + bytes(40),
                                     b"\x00\x01\x00\x00" + struct.pack("<iII", 1, 2, 10**6) + bytes(300)])
def test_a_damaged_message_is_one_logged_error_and_nothing_published(node, damaged):
    published, _ = node.captured
    callback = next(s.callback for s in node.subscriptions if s.topic_name.endswith("imu/data_raw"))
    before, errors = len(published), node._boundary.errors["imu"]
    callback(damaged)  # must not raise: the executor would end
    assert len(published) == before
    assert node._boundary.errors["imu"] == errors + 1


def _with_frame_bytes(frame: bytes, z: float = 9.8) -> bytes:
    """A little-endian Imu whose frame_id is these bytes (any bytes: a driver's, not Python's text)."""
    msg = Imu()
    msg.header.frame_id = "x" * len(frame)
    msg.linear_acceleration.z = z
    msg.angular_velocity.x = 0.25
    raw = bytearray(serialize_message(msg))
    raw[FRAME_AT:FRAME_AT + len(frame)] = frame
    return bytes(raw)


@pytest.mark.parametrize("frame", [b"\xff\xfe", b"imu_\xc3", b"\x80" * 7, b"caf\xe9_link"])
def test_a_frame_id_that_is_not_utf8_is_published_as_rclpy_publishes_it(node, frame):
    """rclpy decodes such a frame_id (each bad byte U+FFFD) and publishes the message: so does the bytes path,
    the same bytes, for every message of such a stream."""
    published, _ = node.captured
    node._stream.enabled = True
    errors, before = node._boundary.errors["imu"], len(published)
    raws = [_with_frame_bytes(frame, z=9.8 + k / 100) for k in range(20)]
    callback = next(s.callback for s in node.subscriptions if s.topic_name.endswith("imu/data_raw"))
    for raw in raws:
        callback(raw)
    assert node._boundary.errors["imu"] == errors and len(published) == before + 20
    for raw, out in zip(raws, published[before:]):
        expected = deserialize_message(raw, Imu)
        node._imu.take(expected)
        assert sent_bytes(out) == sent_bytes(published.pop())
    assert node._stream.frame_id == frame.decode(errors="replace")


@pytest.mark.parametrize("little_endian", [True, False])
def test_a_frame_id_length_of_zero_is_a_damaged_message(node, little_endian):
    """A CDR string's length counts its NUL: 0 is no string at all, and what follows would be read shifted."""
    from rosbags.typesys import Stores, get_typestore

    published, _ = node.captured
    msg = Imu()
    msg.header.frame_id = "imu_link"
    msg.linear_acceleration.z = 9.8
    raw = bytes(serialize_message(msg))
    if not little_endian:
        store = get_typestore(Stores.ROS2_JAZZY)
        raw = bytes(store.serialize_cdr(store.deserialize_cdr(raw, "sensor_msgs/msg/Imu"), "sensor_msgs/msg/Imu",
                                        little_endian=False))
    damaged = raw[:12] + bytes(4) + raw[16:]
    callback = next(s.callback for s in node.subscriptions if s.topic_name.endswith("imu/data_raw"))
    before, errors = len(published), node._boundary.errors["imu"]
    callback(damaged)
    assert len(published) == before
    assert node._boundary.errors["imu"] == errors + 1


def test_a_huge_frame_id_is_not_written_whole_into_the_log(node):
    published, _ = node.captured
    lines: list[str] = []

    class Recorder:
        def __getattr__(self, level):
            return lambda message, **kwargs: lines.append(message)

    log, node._stream._log = node._stream._log, Recorder()
    try:
        for frame in ("h" * 200_000, "imu_link"):
            msg = Imu()
            msg.header.frame_id = frame
            node._imu.take_cdr(bytes(serialize_message(msg)))
    finally:
        node._stream._log = log
    assert lines and all(len(line) < 400 for line in lines), [len(line) for line in lines]
    assert any("200000 characters" in line for line in lines)


def test_the_alignment_padding_is_not_part_of_what_is_compared(node):
    """rclpy's serialiser leaves the padding between the frame_id's NUL and the first double as it finds the
    buffer's memory: a message serialised after one with a longer frame_id of the same size carries that
    one's characters there. The bytes path passes its input's padding on, the message path's output gets a
    new buffer's: equal messages, padding apart. A process whose heap earlier tests have dirtied (the whole
    suite in one process) compared those bytes, and failed at random."""
    published, _ = node.captured
    node._stream.enabled = True
    longer = Imu()
    longer.header.frame_id = "imu_link_7"
    msg = Imu()
    msg.header.frame_id = "imu_link"
    msg.linear_acceleration.z = 9.8
    serialize_message(longer)  # its buffer freed, then reused by the next one of its size
    raw = bytes(serialize_message(msg))
    offsets = imu_offsets(raw)
    padding = raw[offsets.frame_end + 1:offsets.gyro - ORIENTATION_BEFORE_GYRO]
    assert padding.strip(b"\0"), "the padding came out clean: this test no longer shows what it is for"
    node._imu.take(deserialize_message(raw, Imu))
    node._imu.take_cdr(raw)
    longer.header.frame_id = "imu_link_9"
    serialize_message(longer)  # the message path's output is serialised into memory that held other characters
    assert sent_bytes(published[-1]) == sent_bytes(published[-2])
