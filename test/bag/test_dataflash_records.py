"""DataFlash records read with numpy a block at a time (bag/dataflash_records.py) against pymavlink's
DFReader, the reference: every field of every record type of a real log and of the simulated flight logs,
whatever the block size; damage refused as before; a read of the ground only keeps exactly the ground's
samples, and as many as the ground has, however long the flight."""
from __future__ import annotations

import array

import numpy as np
import pytest
from conftest import shared_path
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from accel_calibration.bag.dataflash import DataflashError, read_dataflash, scan_messages
from accel_calibration.bag.dataflash_records import TAIL_BYTES, iter_records, read_records
from msg_tools.dataflash_writer import FORMATS_3X, imu_records_3x, parameter_records, write_dataflash

from helpers import flight_logs
from helpers.flight_logs import FilterBias, fly, sensors, true_in_force, write_dataflash_flight

REAL_LOG = "real/ardupilot/test.BIN"
MARGIN_S = 2.0


def pymavlink_records(path) -> tuple[dict[str, list[dict]], dict[str, float]]:
    """Every record as pymavlink decodes it, by type, and its parameters."""
    from pymavlink import DFReader

    log = DFReader.DFReader_binary(str(path), zero_time_base=False)
    try:
        found: dict[str, list[dict]] = {}
        while (message := log.recv_msg()) is not None:
            found.setdefault(message.get_type(), []).append(message.to_dict())
        return found, {str(k): float(v) for k, v in log.params.items()}
    finally:
        log.close()


def assert_same_as_pymavlink(path, block_bytes: int = 1 << 22) -> None:
    reference, params = pymavlink_records(path)
    log = read_records(path, list(reference), block_bytes=block_bytes)
    assert sorted(log.records) == sorted(reference)
    for name, rows in reference.items():
        mine = log.records[name]
        assert len(mine) == len(rows), name
        assert log.counts[name] == len(rows), name
        assert list(mine.dtype.names) == [c for c in rows[0] if c != "mavpackettype"], name
        for column in mine.dtype.names:
            want = [list(r[column]) if isinstance(r[column], array.array) else r[column] for r in rows]
            have = mine[column].tolist()
            same = [w == h or (isinstance(w, float) and np.isnan(w) and np.isnan(h)) for w, h in zip(want, have)]
            assert all(same), f"{name}.{column}: {want[same.index(False)]!r} != {have[same.index(False)]!r}"
    assert log.params == params


def two_imu_flight(path, **kwargs) -> None:
    truths = sensors(3)
    write_dataflash_flight(path, fly(truths, 4), [true_in_force(t) for t in truths], **kwargs)


def old_style_log(path) -> None:
    """ArduPilot before 4.0: IMU, IMU2, IMU3 for instances 0, 1, 2, no instance field; a parameter set twice."""
    t_us = 5_000_000 + np.arange(300, dtype=np.int64) * 2500
    rng = np.random.default_rng(2)
    records = parameter_records(4_000_000, {"INS_ACCOFFS_X": 0.1, "AHRS_ORIENTATION": 0.0})
    for instance in range(3):
        records += imu_records_3x(t_us, rng.normal(0, 1, (300, 3)), rng.normal(0, 0.1, (300, 3)),
                                  np.full(300, 31.0 + instance), instance)
    records += parameter_records(6_000_000, {"INS_ACCOFFS_X": 0.25})
    write_dataflash(path, FORMATS_3X, records)


def test_every_field_of_the_real_log_is_pymavlinks():
    assert_same_as_pymavlink(shared_path(REAL_LOG))


@pytest.mark.parametrize("kind", ["ekf3", "ekf2", "ekf3 before 4.1", "old imu types"])
def test_every_field_of_the_flight_logs_is_pymavlinks(tmp_path, kind):
    path = tmp_path / "flight.bin"
    if kind == "old imu types":
        old_style_log(path)
    else:
        biases = [FilterBias(np.array([0.02, -0.01, 0.03]), np.array([1e-3, -2e-3, 5e-4]))] * 2
        two_imu_flight(path, biases=biases, ekf=2 if kind == "ekf2" else 3, old_style="before" in kind)
    assert_same_as_pymavlink(path)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(block_bytes=st.one_of(st.integers(1, 600), st.integers(600, 70_000)))
def test_the_block_size_changes_nothing(tmp_path, block_bytes):
    path = tmp_path / "flight.bin"
    if not path.exists():
        two_imu_flight(path)
    whole = read_records(path, ["IMU", "PARM", "ARM", "EV", "FMT"])
    blocks = read_records(path, ["IMU", "PARM", "ARM", "EV", "FMT"], block_bytes=block_bytes)
    assert whole.params == blocks.params and whole.counts == blocks.counts
    assert whole.imu_instances == blocks.imu_instances == (0, 1)
    for name, rows in whole.records.items():
        assert np.array_equal(rows, blocks.records[name]), name
    pieces = [block["IMU"] for block in iter_records(path, ["IMU"], block_bytes=block_bytes) if "IMU" in block]
    assert np.array_equal(np.concatenate(pieces), whole.records["IMU"])
    real = shared_path(REAL_LOG)
    assert read_records(real, ["NKF1", "PARM"]).records["NKF1"].tolist() == \
        read_records(real, ["NKF1", "PARM"], block_bytes=block_bytes).records["NKF1"].tolist()


@pytest.mark.parametrize("kind", ["today", "old imu types"])
def test_iter_records_gives_every_imu_instance(tmp_path, kind):
    path = tmp_path / "log.bin"
    old_style_log(path) if kind == "old imu types" else two_imu_flight(path)
    reference, _ = pymavlink_records(path)
    per_instance: dict[int, int] = {}
    for block in iter_records(path, ["IMU", "IMU2", "IMU3"], block_bytes=4096):
        for name, rows in block.items():
            if name == "IMU" and "I" in rows.dtype.names:
                for instance in np.unique(rows["I"]).tolist():
                    per_instance[instance] = per_instance.get(instance, 0) + int(np.sum(rows["I"] == instance))
            else:
                instance = ("IMU", "IMU2", "IMU3").index(name)
                per_instance[instance] = per_instance.get(instance, 0) + len(rows)
    expected: dict[int, int] = {}
    for name in ("IMU", "IMU2", "IMU3"):
        for row in reference.get(name, []):
            instance = int(row.get("I", ("IMU", "IMU2", "IMU3").index(name)))
            expected[instance] = expected.get(instance, 0) + 1
    assert per_instance == expected and len(expected) == (3 if kind == "old imu types" else 2)


@pytest.mark.parametrize("instance", [0, 1, 2])
def test_read_dataflash_gives_pymavlinks_samples_of_old_logs(tmp_path, instance):
    path = tmp_path / "old.bin"
    old_style_log(path)
    reference, params = pymavlink_records(path)
    rows = reference[("IMU", "IMU2", "IMU3")[instance]]
    samples = read_dataflash(path, instance)
    assert samples.t_ns.tolist() == [r["TimeUS"] * 1000 for r in rows]
    assert samples.accel_mps2.tolist() == [[r["AccX"], r["AccY"], r["AccZ"]] for r in rows]
    assert samples.gyro_radps.tolist() == [[r["GyrX"], r["GyrY"], r["GyrZ"]] for r in rows]
    assert samples.temperature is not None and samples.temperature[1].tolist() == [r["T"] for r in rows]
    assert samples.imu_instances == (0, 1, 2) and samples.samples_read == len(rows)
    assert params["INS_ACCOFFS_X"] == pytest.approx(0.25) and samples.autopilot_calibration is None  # no scale


def test_scan_messages_gives_the_filters_records_scaled(tmp_path):
    path = tmp_path / "ekf.bin"
    two_imu_flight(path, biases=[FilterBias(np.array([0.02, -0.01, 0.03]), np.zeros(3))] * 2)
    found, params = scan_messages(path, ["XKF1", "XKF2"])
    reference, _ = pymavlink_records(path)
    assert found["XKF2"]["AX"].tolist() == [r["AX"] for r in reference["XKF2"]]
    assert params["EK3_IMU_MASK"] == 3.0


# ------------------------------------------------------------------------------------------------ damage
def read_whole_or_error(path) -> tuple[int, str]:
    try:
        return len(read_dataflash(path).t_ns), ""
    except DataflashError as error:
        return -1, str(error)


def test_a_record_cut_by_the_end_of_the_file_ends_the_log_as_in_pymavlink(tmp_path):
    path = tmp_path / "cut.bin"
    two_imu_flight(path)
    data = path.read_bytes()
    for cut in (10, 700, 5000):
        path.write_bytes(data[:-cut])
        reference, _ = pymavlink_records(path)
        assert read_whole_or_error(path)[0] == sum(1 for r in reference["IMU"] if r["I"] == 0) > 0


def test_garbage_in_the_last_bytes_is_the_ends_and_not_damage(tmp_path):
    path = tmp_path / "tail.bin"
    two_imu_flight(path)
    whole = read_whole_or_error(path)[0]
    data = path.read_bytes()
    path.write_bytes(data + b"\x00" * (TAIL_BYTES - 100))
    assert read_whole_or_error(path)[0] == whole
    path.write_bytes(data + b"\x00" * (TAIL_BYTES + 100))
    count, said = read_whole_or_error(path)
    assert count == -1 and "damaged DataFlash log" in said and "\n" not in said


@pytest.mark.parametrize("damage", ["a byte more", "an unknown type"])
def test_bad_bytes_within_the_log_are_refused_in_one_line(tmp_path, damage):
    path = tmp_path / "bad.bin"
    two_imu_flight(path)
    data = bytearray(path.read_bytes())
    at = data.find(b"\xa3\x95", len(data) // 2)
    if damage == "a byte more":
        data[at:at] = b"\x07"
    else:
        data[at + 2] = 0x7F
    path.write_bytes(bytes(data))
    count, said = read_whole_or_error(path)
    assert count == -1 and said.startswith(f"{path}: damaged DataFlash log") and "\n" not in said
    assert f"offset {at}" in said


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(changes=st.lists(st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.integers(0, 255)), max_size=6),
       cut=st.one_of(st.none(), st.floats(0.0, 1.0)))
def test_a_mutated_log_is_read_or_refused_in_one_line(tmp_path, changes, cut):
    path = tmp_path / "mutated.bin"
    old_style_log(path)
    data = bytearray(path.read_bytes())
    for where, value in changes:
        data[int(where * len(data))] = value
    if cut is not None:
        data = data[: int(cut * len(data))]
    path.write_bytes(bytes(data))
    for instance in (0, 2):
        try:
            read_dataflash(path, instance, ground_margin_s=MARGIN_S)
        except DataflashError as error:
            assert "\n" not in str(error)


# ----------------------------------------------------------------------------------------- ground only
def test_the_ground_read_keeps_exactly_the_ground_samples(tmp_path):
    path = tmp_path / "flight.bin"
    two_imu_flight(path)
    for instance in (0, 1):
        whole = read_dataflash(path, instance)
        ground = read_dataflash(path, instance, ground_margin_s=MARGIN_S)
        kept = whole.flight_state.ground_kept(whole.t_ns, MARGIN_S)
        assert 0 < kept.sum() < len(kept)
        assert np.array_equal(ground.t_ns, whole.t_ns[kept])
        assert np.array_equal(ground.accel_mps2, whole.accel_mps2[kept])
        assert np.array_equal(ground.gyro_radps, whole.gyro_radps[kept])
        assert ground.temperature is not None and whole.temperature is not None
        assert np.array_equal(ground.temperature[1], whole.temperature[1][kept])
        collecting = whole.flight_state.collecting(whole.t_ns, MARGIN_S)
        assert np.array_equal(ground.t_ns[ground.flight_state.collecting(ground.t_ns, MARGIN_S)],
                              whole.t_ns[collecting])
        assert np.array_equal(ground.flight_state.spans_ns, whole.flight_state.spans_ns)
        assert ground.samples_read == whole.samples_read == len(whole.t_ns)
        assert ground.first_last_ns == whole.first_last_ns == (int(whole.t_ns[0]), int(whole.t_ns[-1]))


def test_the_ground_read_of_a_long_flight_keeps_the_ground_seconds(tmp_path, monkeypatch):
    monkeypatch.setattr(flight_logs, "FLIGHT_S", 900.0)  # a 15-minute flight between 10 s on the ground each side
    path = tmp_path / "long.bin"
    truths = sensors(5, 1)
    flight = fly(truths, 6)
    write_dataflash_flight(path, flight, [true_in_force(truths[0])])
    ground = read_dataflash(path, 0, ground_margin_s=MARGIN_S)
    rate, border = flight_logs.RATE_HZ, 1.0
    ground_s = 2 * (flight_logs.GROUND_S - MARGIN_S + border)  # before arming and after disarming, each side
    assert ground.samples_read == len(flight.t_us)
    assert abs(len(ground.t_ns) - ground_s * rate) <= 4  # the ground's, not the flight's 90,000
    assert ground.first_last_ns == (int(flight.t_us[0]) * 1000, int(flight.t_us[-1]) * 1000)


def test_an_fmt_record_that_redefines_a_type_after_its_records_is_refused_in_one_line(tmp_path):
    """pymavlink reads the records after it with the new layout and those before with the old: two tables
    of one name that no array holds together. Said, not read half one way."""
    path = tmp_path / "redefined.bin"
    two_imu_flight(path)
    data = path.read_bytes()
    fmt_of_imu = data.find(b"\xa3\x95\x80\x82")  # FORMATS_4X's second type: IMU
    redefined = bytearray(data[fmt_of_imu:fmt_of_imu + 89])
    assert redefined[5:25] == b"IMU\0" + b"QBffffffIIfBBHH".ljust(16, b"\0")  # Name, Format
    redefined[25:89] = b"TimeUS,J,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz".ljust(64, b"\0")  # Columns
    middle = data.find(b"\xa3\x95", len(data) // 2)
    path.write_bytes(data[:middle] + bytes(redefined) + data[middle:])
    count, said = read_whole_or_error(path)
    assert count == -1 and said == (f"{path}: damaged DataFlash log: the FMT record at offset {middle} redefines "
                                    "IMU (type 130) after records of it")


def test_fmtu_names_the_instance_field_and_mult_scales_no_value_as_in_pymavlink(tmp_path):
    """FMTU's unit `#` marks a type's instance field; MULT and UNIT records only name units: pymavlink
    scales no value by them, nor do we."""
    from pymavlink import DFReader

    from msg_tools.dataflash_writer import FORMATS_4X, imu_records

    formats = {**FORMATS_4X, "UNIT": ("QbZ", "TimeUS,Id,Label"), "MULT": ("Qbd", "TimeUS,Id,Mult"),
               "FMTU": ("QBNN", "TimeUS,FmtType,UnitIds,MultIds")}
    imu_type = 0x81 + list(formats).index("IMU")
    t_us = 1_000_000 + np.arange(50, dtype=np.int64) * 1000
    records = [("UNIT", (900_000, ord("E"), "rad/s")), ("MULT", (900_000, ord("B"), 1e-2)),
               ("FMTU", (900_000, imu_type, "s#EEEnnn--O--zz", "F-BBBBBB--B----")),
               *imu_records(t_us, np.full((50, 3), 9.8), np.full((50, 3), 0.25), np.full(50, 30.0), instance=1)]
    path = tmp_path / "units.bin"
    write_dataflash(path, formats, records)
    assert_same_as_pymavlink(path)
    reference = DFReader.DFReader_binary(str(path), zero_time_base=False)
    try:  # closed here: left to the garbage collector, its file warns in whichever test runs then
        instance_field = reference.formats[imu_type].instance_field
    finally:
        reference.close()
    assert read_records(path, []).formats["IMU"].instance_field == instance_field == "I"
    assert read_records(path, ["IMU"]).records["IMU"]["GyrX"].tolist() == [0.25] * 50


def test_imu_records_without_an_acceleration_field_are_one_line(tmp_path):
    formats = {"IMU": ("QBfff", "TimeUS,I,GyrX,GyrY,GyrZ")}
    path = tmp_path / "gyro_only.bin"
    write_dataflash(path, formats, [("IMU", (1_000_000 + 1000 * k, 0, 0.0, 0.0, 0.0)) for k in range(20)])
    count, said = read_whole_or_error(path)
    assert count == -1 and said == f"{path}: unreadable DataFlash log (its IMU records have no AccX field)"
