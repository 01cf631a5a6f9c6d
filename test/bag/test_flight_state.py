"""Flight recordings carry their own flight state: a ULog's vehicle_status and
vehicle_land_detected, a bag's /mavros/state, /fmu/out/vehicle_status(+land detected) or a topic named with
--armed-topic, a DataFlash log's ARM and EV records. The recording written here: a ground session (8
orientations), the vehicle set level, armed and still for 3 s on the ground, a quiet hover (tilted 4 deg,
noise like the ground's: a well-damped IMU, so the detector alone would take it for a pose), landing, 3 s
still, disarming, 5 s still, 8 more ground orientations. In every format: no pose has a sample between
arming - margin and disarming + margin, the calibration is the one the ground segments alone give, and the
same recording without its flight-state records says so in one line. Without the flight state (or with
--ignore-flight-state) poses come from the flight: the checks can fail."""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from scipy.spatial.transform import Rotation, Slerp

from accel_calibration.bag.dataflash import read_dataflash
from accel_calibration.bag.flight_sources import FlightStateError, field_test
from accel_calibration.bag.replay import ReplaySettings, replay_bag
from accel_calibration.cli.main import main
from accel_calibration.core import flight_state as fs
from accel_calibration.core.session import CalibrationSession
from msg_tools.dataflash_writer import FORMATS_4X, imu_records, write_dataflash
from msg_tools.synthetic_imu import SensorErrors, rotation_with_up, spread_orientations
from msg_tools.ulog_writer import sensor_combined_array, write_ulog

G = 9.80665
RATE_HZ = 200.0
MARGIN_S = 2.0
MOVE_S = 1.5
START_NS = 1_700_000_000 * 10**9  # a bag's clock
START_US = 7_000_000  # a log's clock: us since boot
LINE = re.compile(r"^left out (\d+\.\d) s armed or airborne \((.+)\)$")


@dataclass(frozen=True)
class Flight:
    t_ns: np.ndarray  # from 0
    accel: np.ndarray
    gyro: np.ndarray
    temperature_degc: np.ndarray
    arm_ns: int
    liftoff_ns: int
    touchdown_ns: int
    disarm_ns: int
    errors: SensorErrors

    def status(self, period_s: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(stamps ns, armed, landed) as a flight stack publishes them: periodically and at each change."""
        periodic = np.arange(0, int(self.t_ns[-1]), int(period_s * 1e9), dtype=np.int64)
        stamps = np.unique(np.concatenate([periodic, [self.arm_ns, self.liftoff_ns, self.touchdown_ns,
                                                      self.disarm_ns]]))
        armed = (stamps >= self.arm_ns) & (stamps < self.disarm_ns)
        landed = ~((stamps >= self.liftoff_ns) & (stamps < self.touchdown_ns))
        return stamps, armed, landed


def make_flight(seed: int = 5) -> Flight:
    rng = np.random.default_rng(seed)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    ground = spread_orientations(16, rng)
    level = rotation_with_up([0.0, 0.0, 1.0])
    hover = level * Rotation.from_euler("xy", [4.0, -3.0], degrees=True)
    holds: list[tuple[Rotation, float, str]] = [(r, 3.0, "") for r in ground[:8]]
    # Set level 0.2 s before arming - margin (shorter than a pose), armed and still for 3 s, take-off.
    holds += [(level, 0.2 + MARGIN_S + 3.0, "armed"), (hover, 11.0, "hover"), (level, 3.0 + 5.0 + MARGIN_S, "landed")]
    holds += [(r, 3.0, "") for r in ground[8:]]
    keys, rotations, starts = [], [], []
    t = 0.0
    for rotation, hold_s, _ in holds:
        starts.append(t)
        keys += [t, t + hold_s]
        rotations += [rotation, rotation]
        t += hold_s + MOVE_S
    duration = keys[-1]
    stamps_s = np.arange(int(duration * RATE_HZ) + 1) / RATE_HZ
    turn = Slerp(keys, Rotation.concatenate(rotations))
    # A body->world rotation per sample, and one a sample later for the body rate.
    body = turn(stamps_s)
    later = turn(np.minimum(stamps_s + 1.0 / RATE_HZ, duration))
    accel_true = body.inv().apply([0.0, 0.0, G])
    gyro_true = (body.inv() * later).as_rotvec() * RATE_HZ
    accel = errors.raw_from_true(accel_true) + rng.normal(0.0, errors.noise_mps2, accel_true.shape)
    gyro = gyro_true + errors.gyro_bias_radps + rng.normal(0.0, errors.gyro_noise_radps, gyro_true.shape)
    armed_start = starts[8]
    arm_s = armed_start + 0.2 + MARGIN_S
    liftoff_s = arm_s + 3.0 + MOVE_S / 2
    touchdown_s = starts[9] + 11.0 + MOVE_S / 2
    disarm_s = starts[10] + 3.0
    ns = [int(round(x * 1e9)) for x in (arm_s, liftoff_s, touchdown_s, disarm_s)]
    t_ns = np.round(stamps_s * 1e9).astype(np.int64)
    # float32 samples, as a ULog and a DataFlash log store them: every format then holds the same values.
    as_stored = np.float32
    return Flight(t_ns, accel.astype(as_stored).astype(float), gyro.astype(as_stored).astype(float),
                  (30.0 + 0.01 * stamps_s).astype(as_stored).astype(float), *ns, errors)


@pytest.fixture(scope="module")
def flight() -> Flight:
    return make_flight()


def ground_alone(flight: Flight, offset_ns: int = 0):
    """The calibration from the ground segments alone (before arming - margin, after disarming + margin),
    each through its own session, their poses fitted together."""
    margin = int(MARGIN_S * 1e9)
    fitting = CalibrationSession()
    found = 0
    for keep in (flight.t_ns < flight.arm_ns - margin, flight.t_ns > flight.disarm_ns + margin):
        session = CalibrationSession()
        for pose in session.add_recording(flight.t_ns[keep] + offset_ns, flight.accel[keep], flight.gyro[keep]):
            fitting.add_pose(pose)
            found += 1
    verdict = fitting.calibrate()
    assert verdict.success, verdict.message
    return verdict.calibration, found


def assert_ground_only(replay, flight: Flight, offset_ns: int, sources: str, bias_atol: float = 1e-7):
    assert replay.problem is None, replay.problem
    low, high = offset_ns + flight.arm_ns - int(MARGIN_S * 1e9), offset_ns + flight.disarm_ns + int(MARGIN_S * 1e9)
    assert replay.poses and all(p.end_ns < low or p.start_ns > high for p in replay.poses)
    assert replay.flight_state.found
    match = LINE.match(replay.flight_state.line)
    assert match, replay.flight_state.line
    assert float(match.group(1)) == pytest.approx((high - low) / 1e9, abs=0.051)
    assert match.group(2) == sources
    reference, poses = ground_alone(flight, offset_ns)
    assert len(replay.poses) == poses == 17  # 16 orientations, level after disarming + margin
    ours = replay.calibration
    # The same samples in the same poses: the same calibration, to float rounding (0.00001 mg).
    np.testing.assert_allclose(ours.bias, reference.bias, rtol=0, atol=bias_atol)
    np.testing.assert_allclose(ours.matrix, reference.matrix, rtol=0, atol=bias_atol / 10)


def assert_flight_leaks_without(path, flight: Flight, offset_ns: int, **options):
    """Without the flight state the hover and the 3 s armed on the ground are poses: the checks above can fail."""
    replay = replay_bag(path, ReplaySettings(ignore_flight_state=True, **options))
    assert replay.flight_state is None
    arm, disarm = offset_ns + flight.arm_ns, offset_ns + flight.disarm_ns
    inside = [p for p in replay.poses if p.end_ns > arm and p.start_ns < disarm]
    assert len(inside) >= 2  # armed on the ground, the hover (and landed, before disarming)


def assert_warns_none_found(path, capsys):
    replay = replay_bag(path)
    assert not replay.flight_state.found
    assert replay.flight_state.line.startswith("no flight state in this recording")
    main(["replay", str(path)])
    out = capsys.readouterr().out
    warnings = [line for line in out.splitlines() if line.startswith("warning: no flight state")]
    assert len(warnings) == 1


# ------------------------------------------------------------------------------------------------- ULog
def write_flight_ulog(path, flight: Flight, with_state: bool = True) -> None:
    t_us = START_US + flight.t_ns // 1000
    topics = [("sensor_combined", 0, sensor_combined_array(t_us, flight.accel, flight.gyro))]
    if with_state:
        stamps, armed, landed = flight.status()
        status = np.zeros(len(stamps), dtype=[("timestamp", "<u8"), ("nav_state", "u1"), ("arming_state", "u1")])
        status["timestamp"] = START_US + stamps // 1000
        status["arming_state"] = np.where(armed, 2, 1)
        land = np.zeros(len(stamps), dtype=[("timestamp", "<u8"), ("freefall", "u1"), ("landed", "u1")])
        land["timestamp"] = status["timestamp"]
        land["landed"] = landed
        topics += [("vehicle_status", 0, status), ("vehicle_land_detected", 0, land)]
    write_ulog(path, topics)


def test_ulog_vehicle_status_and_land_detected_keep_the_flight_out(flight, tmp_path, capsys):
    path = tmp_path / "flight.ulg"
    write_flight_ulog(path, flight)
    replay = replay_bag(path)
    assert_ground_only(replay, flight, START_US * 1000, "PX4 vehicle_status, vehicle_land_detected")
    assert_flight_leaks_without(path, flight, START_US * 1000)
    assert main(["replay", str(path)]) == 0
    out = capsys.readouterr().out
    assert sum(line.startswith("left out ") for line in out.splitlines()) == 1
    bare = tmp_path / "bare.ulg"
    write_flight_ulog(bare, flight, with_state=False)
    assert_warns_none_found(bare, capsys)


# ------------------------------------------------------------------------------------------------- bags
MAVROS_STATE = """std_msgs/Header header
bool connected
bool armed
bool guided
bool manual_input
string mode
uint8 system_status
"""
# px4_msgs as PX4 v1.15 defines them, cut to the fields read (the bag records what it was written with).
VEHICLE_STATUS = """uint64 timestamp
uint64 armed_time
uint8 ARMING_STATE_DISARMED = 1
uint8 ARMING_STATE_ARMED = 2
uint8 arming_state
uint8 nav_state
"""
VEHICLE_LAND_DETECTED = """uint64 timestamp
float32 alt_max
bool freefall
bool ground_contact
bool maybe_landed
bool landed
"""


def typestore_with_flight_types():
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for text, name in ((MAVROS_STATE, "mavros_msgs/msg/State"), (VEHICLE_STATUS, "px4_msgs/msg/VehicleStatus"),
                       (VEHICLE_LAND_DETECTED, "px4_msgs/msg/VehicleLandDetected")):
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def write_flight_bag(path, flight: Flight, storage: str, state: str | None) -> None:
    """IMU on /imu/data_raw (header stamps = record times) and the flight state as `state` says:
    "mavros", "px4" (vehicle_status + vehicle_land_detected), "bool" (/armed std_msgs/Bool), None."""
    store = typestore_with_flight_types()
    types = store.types
    Header, Time, Vector3 = (types["std_msgs/msg/Header"], types["builtin_interfaces/msg/Time"],
                             types["geometry_msgs/msg/Vector3"])

    def header(t):
        sec, nanosec = divmod(int(t), 1_000_000_000)
        return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id="imu_link")

    records = []
    stamps, armed, landed = flight.status()
    for k, t in enumerate((START_NS + stamps).tolist()):
        if state == "mavros":
            records.append((t, "/mavros/state", "mavros_msgs/msg/State", types["mavros_msgs/msg/State"](
                header=header(t), connected=True, armed=bool(armed[k]), guided=False, manual_input=True,
                mode="STABILIZED", system_status=4 if armed[k] else 3)))
        elif state == "px4":
            boot_us = int(stamps[k] // 1000)  # the autopilot's own clock: not the IMU's
            records.append((t, "/fmu/out/vehicle_status", "px4_msgs/msg/VehicleStatus",
                            types["px4_msgs/msg/VehicleStatus"](timestamp=boot_us, armed_time=0,
                                                                arming_state=2 if armed[k] else 1, nav_state=0)))
            records.append((t, "/fmu/out/vehicle_land_detected", "px4_msgs/msg/VehicleLandDetected",
                            types["px4_msgs/msg/VehicleLandDetected"](timestamp=boot_us, alt_max=-1.0, freefall=False,
                                                                      ground_contact=False, maybe_landed=False,
                                                                      landed=bool(landed[k]))))
        elif state == "bool":
            records.append((t, "/armed", "std_msgs/msg/Bool", types["std_msgs/msg/Bool"](data=bool(armed[k]))))
    Imu, Quaternion = types["sensor_msgs/msg/Imu"], types["geometry_msgs/msg/Quaternion"]
    no_orientation = np.r_[-1.0, np.zeros(8)]
    for t, a, g in zip((START_NS + flight.t_ns).tolist(), flight.accel, flight.gyro):
        records.append((t, "/imu/data_raw", "sensor_msgs/msg/Imu", Imu(
            header=header(t), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=no_orientation, angular_velocity=Vector3(x=g[0], y=g[1], z=g[2]),
            angular_velocity_covariance=np.zeros(9), linear_acceleration=Vector3(x=a[0], y=a[1], z=a[2]),
            linear_acceleration_covariance=np.zeros(9))))
    records.sort(key=lambda r: r[0])
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        connections = {}
        for t, topic, msgtype, message in records:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], t, store.serialize_cdr(message, msgtype))


@pytest.mark.parametrize("storage, state, options, sources", [
    ("mcap", "mavros", {}, "/mavros/state armed"),
    ("sqlite3", "px4", {}, "/fmu/out/vehicle_status arming_state == 2, /fmu/out/vehicle_land_detected not landed"),
    ("mcap", "bool", {"armed_topic": "/armed"}, "/armed data"),
    ("mcap", "mavros", {"armed_topic": "/mavros/state", "armed_field": "system_status >= 4"},
     "/mavros/state system_status >= 4"),
])
def test_bag_flight_state_topics_keep_the_flight_out(flight, tmp_path, storage, state, options, sources):
    path = tmp_path / "flight"
    write_flight_bag(path, flight, storage, state)
    replay = replay_bag(path, ReplaySettings(**options))
    assert_ground_only(replay, flight, START_NS, sources)
    if state == "mavros" and not options:
        assert_flight_leaks_without(path, flight, START_NS)
        # Through rosbags, message by message: the same.
        through = replay_bag(path, ReplaySettings(), through_rosbags=True)
        assert [p.start_ns for p in through.poses] == [p.start_ns for p in replay.poses]


def test_bag_without_flight_state_topics_warns_in_one_line(flight, tmp_path, capsys):
    path = tmp_path / "bare"
    write_flight_bag(path, flight, "mcap", None)
    assert_warns_none_found(path, capsys)


def test_bad_flight_state_options_are_one_line(flight, tmp_path, capsys):
    path = tmp_path / "flight"
    write_flight_bag(path, flight, "mcap", "bool")
    cases = [
        (["--armed-topic", "/nope"], "--armed-topic /nope is not in the bag"),
        (["--armed-topic", "/armed", "--armed-field", "missing"], "has no field 'missing'"),
        (["--armed-topic", "/armed", "--armed-field", "data = 1"], "write FIELD"),
        (["--armed-field", "data"], "--armed-field needs --armed-topic"),
        (["--armed-margin-s", "-1"], "--armed-margin-s must be from 0"),
    ]
    for extra, message in cases:
        assert main(["replay", str(path), *extra]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
    ulog = tmp_path / "x.ulg"
    write_flight_ulog(ulog, flight)
    assert main(["replay", str(ulog), "--armed-topic", "/armed"]) == 1
    assert "apply to bags" in capsys.readouterr().err


def test_field_expressions():
    class Message:
        armed, arming_state, header = True, 2, type("H", (), {"frame_id": "x"})()

    assert field_test("armed")(Message()) and not field_test("not armed")(Message())
    assert field_test("arming_state == 2")(Message()) and not field_test("arming_state != 2")(Message())
    assert field_test("arming_state > 1.5")(Message()) and field_test("armed == true")(Message())
    for bad in ("__import__('os')", "armed ==", "a.b c", "x == y"):
        with pytest.raises(FlightStateError):
            field_test(bad)


# -------------------------------------------------------------------------------------------- DataFlash
DATAFLASH_OFFSETS, DATAFLASH_SCALES = np.array([0.1, -0.2, 0.3]), np.array([1.01, 0.99, 1.0])


def dataflash_logged(flight: Flight) -> np.ndarray:
    """The flight's raw samples as ArduPilot logs them: corrected by its INS_ACCOFFS/SCAL, float32."""
    return ((flight.accel - DATAFLASH_OFFSETS) * DATAFLASH_SCALES).astype(np.float32)


def write_flight_dataflash(path, flight: Flight, with_state: bool = True) -> None:
    t_us = START_US + flight.t_ns // 1000
    params = {"INS_ACCOFFS_X": 0.1, "INS_ACCOFFS_Y": -0.2, "INS_ACCOFFS_Z": 0.3, "INS_ACCSCAL_X": 1.01,
              "INS_ACCSCAL_Y": 0.99, "INS_ACCSCAL_Z": 1.0, "INS_ACC1_CALTEMP": 31.5}
    records = [(START_US, ("PARM", (START_US, name, value))) for name, value in params.items()]
    records += [(int(r[1][0]), r) for r in imu_records(t_us, dataflash_logged(flight), flight.gyro,
                                                       flight.temperature_degc)]
    if with_state:
        arm_us, disarm_us = START_US + flight.arm_ns // 1000, START_US + flight.disarm_ns // 1000
        records += [(arm_us, ("ARM", (arm_us, 1, 0, 0, 0))), (arm_us, ("EV", (arm_us, 10))),
                    (START_US + flight.liftoff_ns // 1000, ("EV", (START_US + flight.liftoff_ns // 1000, 28))),
                    (START_US + flight.touchdown_ns // 1000, ("EV", (START_US + flight.touchdown_ns // 1000, 18))),
                    (disarm_us, ("ARM", (disarm_us, 0, 0, 0, 0))), (disarm_us, ("EV", (disarm_us, 11)))]
    records.sort(key=lambda r: r[0])
    write_dataflash(path, FORMATS_4X, [r for _, r in records])


def test_dataflash_arm_and_ev_keep_the_flight_out_and_the_autopilot_calibration_is_said(flight, tmp_path, capsys):
    path = tmp_path / "flight.bin"
    write_flight_dataflash(path, flight)
    replay = replay_bag(path)
    # Replay undoes the logged correction: the raw samples again, to float32 logging (0.001 mg).
    assert_ground_only(replay, flight, START_US * 1000,
                       "ArduPilot ARM, EV armed/disarmed, EV not landed/land complete", bias_atol=1e-5)
    autopilot = replay.autopilot.calibration
    np.testing.assert_allclose(autopilot.offsets_mps2, [0.1, -0.2, 0.3], rtol=1e-6)
    np.testing.assert_allclose(autopilot.scale, [1.01, 0.99, 1.0], rtol=1e-6)
    assert autopilot.caltemp_degc == pytest.approx(31.5)
    # Ours corrects the raw sensor; how far the autopilot's calibration is from it, worst over orientations,
    # against a brute force over 20,000 directions: the raw outputs ours maps to 1 g, corrected by both.
    ours = replay.calibration
    directions = Rotation.random(20000, random_state=np.random.default_rng(1)).apply([0.0, 0.0, G])
    raw = directions @ np.linalg.inv(ours.matrix).T + ours.bias
    theirs = (raw - DATAFLASH_OFFSETS) * DATAFLASH_SCALES
    brute = np.max(np.linalg.norm(theirs - directions, axis=1)) / (G / 1000)
    assert replay.autopilot.difference_mg == pytest.approx(brute, abs=0.05)
    assert replay.autopilot.difference_mg > 20  # an MPU-6050-like sensor: tens of mg
    assert main(["replay", str(path)]) == 0
    out = capsys.readouterr().out
    assert "the autopilot's calibration at the time (instance 0): offsets +0.1000 -0.2000 +0.3000" in out
    assert f"up to {replay.autopilot.difference_mg:.1f} mg at 1 g" in out
    assert "fitted to raw: DataFlash IMU instance 0 with the log's correction undone" in out
    samples = read_dataflash(path)  # the reader gives the records as logged
    np.testing.assert_array_equal(samples.t_ns, (START_US + flight.t_ns // 1000) * 1000)
    np.testing.assert_array_equal(samples.accel_mps2, dataflash_logged(flight))
    bare = tmp_path / "bare.bin"
    write_flight_dataflash(bare, flight, with_state=False)
    assert_warns_none_found(bare, capsys)


def test_dataflash_instance_option(flight, tmp_path, capsys):
    path = tmp_path / "two.bin"
    t_us = START_US + flight.t_ns[:400] // 1000
    records = imu_records(t_us, flight.accel[:400], flight.gyro[:400], flight.temperature_degc[:400], instance=0)
    records += imu_records(t_us, flight.accel[:400] * 2, flight.gyro[:400], flight.temperature_degc[:400], instance=1)
    write_dataflash(path, FORMATS_4X, records)
    one = read_dataflash(path, instance=1)
    np.testing.assert_array_equal(one.accel_mps2, (flight.accel[:400] * 2).astype(np.float32))
    assert main(["replay", str(path), "--instance", "3"]) == 1
    assert "no IMU instance 3; the log has instance(s) 0, 1" in capsys.readouterr().err


def test_real_dataflash_log_gives_pymavlinks_values_and_says_too_few_poses(shared, capsys):
    from pymavlink import DFReader

    path = shared("real/ardupilot/test.BIN")
    reference = DFReader.DFReader_binary(str(path))
    expected: dict[str, list] = {"IMU": [], "IMU2": []}
    try:  # closed here: left to the garbage collector, its file warns in whichever test runs then
        while (message := reference.recv_match(type=["IMU", "IMU2"])) is not None:
            expected[message.get_type()].append([message.TimeUS, message.AccX, message.AccY, message.AccZ,
                                                 message.GyrX, message.GyrY, message.GyrZ, message.T])
    finally:
        reference.close()
    for instance, kind in ((0, "IMU"), (1, "IMU2")):
        samples = read_dataflash(path, instance=instance)
        want = np.array(expected[kind])
        assert len(want) == 45
        np.testing.assert_array_equal(samples.t_ns, want[:, 0].astype(np.int64) * 1000)
        np.testing.assert_array_equal(samples.accel_mps2, want[:, 1:4])
        np.testing.assert_array_equal(samples.gyro_radps, want[:, 4:7])
        np.testing.assert_array_equal(samples.temperature[1], want[:, 7])
    first = read_dataflash(path)
    assert first.t_ns[0] == 81794643_000 and first.accel_mps2[0, 2] == pytest.approx(-9.780994, abs=1e-6)
    assert first.autopilot_calibration.offsets_mps2[1] == pytest.approx(2.485, abs=1e-3)
    assert first.autopilot_calibration.scale[1] == pytest.approx(0.9025, abs=1e-4)
    assert read_dataflash(path, instance=1).autopilot_calibration.offsets_mps2[1] == pytest.approx(0.2437, abs=1e-4)
    assert main(["replay", str(path)]) == 1
    captured = capsys.readouterr()
    assert captured.err.count("\n") == 1 and "too few static poses" in captured.err


# ------------------------------------------------------------------------------------------------ core
readings = st.lists(st.tuples(st.integers(0, 10_000), st.booleans()), max_size=12, unique_by=lambda r: r[0])


@settings(max_examples=120, deadline=None)
@given(readings, readings, st.integers(0, 500), st.sampled_from([None, False, True]))
def test_collecting_mask_is_the_state_held_at_every_sample_widened_by_the_margin(one, other, margin_ms, initial):
    """Against a brute force: a sample is collected only when no source says flying anywhere within the margin
    either side, ends included (each reading held until the next of its source; before the first, `initial`,
    or when None the first's own)."""
    margin_ns = margin_ms * 1_000_000
    t = np.arange(-1_000, 12_000, 23, dtype=np.int64) * 1_000_000
    sources = []
    for series in (one, other):
        stamps = np.array([s for s, _ in series], dtype=np.int64) * 1_000_000
        states = np.array([f for _, f in series], dtype=bool)
        sources.append(fs.FlightState(fs.spans_from_states(stamps, states, initial), ("x",)))
    mask = fs.combined(sources).collecting(t, margin_ms / 1000)

    def state(series, when, strict):
        """The state held at `when` (strict: just before it)."""
        if not series:
            return False
        ordered = sorted((s * 1_000_000, f) for s, f in series)
        before = [f for s, f in ordered if (s < when if strict else s <= when)]
        if before:
            return before[-1]
        return ordered[0][1] if initial is None else initial

    stamps = sorted({s * 1_000_000 for s, _ in one + other})
    for k, when in enumerate(t.tolist()):
        low, high = when - margin_ns, when + margin_ns
        points = [low, *(s for s in stamps if low <= s <= high)]
        flying = any(state(series, low, True) for series in (one, other)) or any(
            state(series, x, False) for series in (one, other) for x in points)
        assert mask[k] == (not flying), (when, one, other, margin_ms, initial)


def test_left_out_seconds_and_margins():
    spans = fs.spans_from_states(np.array([10, 20], np.int64) * 10**9, np.array([True, False]), initial=False)
    np.testing.assert_array_equal(spans, [[10 * 10**9, 20 * 10**9]])
    assert fs.left_out_s(0, 100 * 10**9, spans, 2.0) == pytest.approx(14.0)
    assert fs.left_out_s(15 * 10**9, 100 * 10**9, spans, 2.0) == pytest.approx(7.0)
    still_armed = fs.spans_from_states(np.array([5], np.int64), np.array([True]))
    assert fs.left_out_s(0, 10**9, still_armed, 2.0) == pytest.approx(1.0)  # armed from before the start to the end
    with pytest.raises(fs.CalibrationError, match="armed-margin-s"):
        fs.collecting_mask(np.zeros(3, np.int64), spans, float("nan"))


def test_fleet_takes_the_same_flight_state_options():
    from accel_calibration.cli.main import _parser
    from accel_calibration.cli.options import replay_settings

    args = _parser().parse_args(["fleet", "somewhere", "--armed-topic", "/armed", "--armed-field", "not data",
                                 "--armed-margin-s", "3.5", "--ignore-flight-state"])
    settings = replay_settings(args)
    assert (settings.armed_topic, settings.armed_field, settings.armed_margin_s, settings.ignore_flight_state) == (
        "/armed", "not data", 3.5, True)


# -------------------------------------------------------------------------------------------- start-up
def test_written_out_jazzy_definitions_are_rosbags_own():
    import hashlib

    from accel_calibration.bag.bag_io import JAZZY_DEFINITIONS

    store = get_typestore(Stores.ROS2_JAZZY)
    for msgtype, (rihs01, text_sha256) in JAZZY_DEFINITIONS.items():
        assert store.hash_rihs01(msgtype) == rihs01
        assert hashlib.sha256(store.generate_msgdef(msgtype, ros_version=2)[0].encode()).hexdigest() == text_sha256


def test_help_and_a_replay_that_draws_nothing_import_no_scipy_linalg_nor_matplotlib(flight, tmp_path):
    """In a fresh interpreter, as a user starts it: scipy.linalg alone costs ~0.36 s of start-up.
    A bag of standard messages only is read without rosbags' Jazzy store (~0.2 s) too."""
    import subprocess
    import sys

    write_flight_bag(tmp_path / "flight", flight, "mcap", "mavros")
    write_flight_bag(tmp_path / "bare", flight, "mcap", None)
    code = ("import contextlib, io, sys\nfrom accel_calibration.cli.main import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    try:\n        code = main(sys.argv[1:])\n    except SystemExit as done:\n        code = done.code\n"
            "print(code, sorted(m for m in sys.modules if m in ('scipy.linalg', 'matplotlib', 'scipy.stats')),"
            " any(m.startswith('rosbags.typesys.stores.') for m in sys.modules))")
    for argv, expected in ((["--help"], "0 [] False"),
                           (["replay", str(tmp_path / "flight"), "-o", str(tmp_path / "a.yaml")], "0 [] True"),
                           (["replay", str(tmp_path / "bare"), "-o", str(tmp_path / "b.yaml")], "0 [] False")):
        done = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, check=True)
        assert done.stdout.strip() == expected, (argv, done.stdout, done.stderr[-500:])


def test_an_mcap_files_topics_from_its_summary_are_what_rosbags_lists(flight, tmp_path, shared):
    from accel_calibration.bag.bag_io import open_reader
    from accel_calibration.bag.mcap_scan import summary_topics

    write_flight_bag(tmp_path / "flight", flight, "mcap", "px4")
    files = [next((tmp_path / "flight").glob("*.mcap")), shared("real/bags/test2_mcap_zstd/test2_mcap_zstd.mcap")]
    for file in files:
        reader = open_reader(file)
        expected = sorted((c.topic, c.msgtype, c.msgcount) for c in reader.connections)
        reader.close()
        assert sorted(summary_topics(file)) == expected
