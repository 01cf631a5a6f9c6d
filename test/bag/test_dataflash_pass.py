"""The fleet's one pass over an ArduPilot DataFlash log (bag/dataflash_pass.py): each IMU's ground rows, its
per-second sums in flight, the flight state and the filter's records read in two walks of the file and kept
for every ask that follows. The rows and the evidence are those of the log read whole, a log rewritten in
place is read again, and a three-IMU log is walked twice where each ask walked it again (nine walks)."""
from __future__ import annotations

import dataclasses
import json
import math
import os
import re
from typing import Any

import numpy as np
import pytest

from accel_calibration.bag import dataflash_pass, in_flight_evidence
from accel_calibration.bag.dataflash import accel_devices
from accel_calibration.bag.dataflash_records import RecordReader, read_records
from accel_calibration.bag.recording import log_accel_devices
from accel_calibration.cli.fleet import calibrate_recording
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

from helpers import flight_logs
from helpers.flight_logs import (
    ALL_DEVICES,
    MG,
    FilterBias,
    FlightLog,
    fly,
    sensors,
    true_in_force,
    write_dataflash_flight,
)

FILTER_BIASES = [FilterBias(np.array(a) * MG, np.array(g)) for a, g in (
    ([2.0, -1.0, 4.0], [1e-3, 0.0, -5e-4]), ([-3.0, 1.0, -2.0], [0.0, 2e-3, 5e-4]),
    ([1.0, 2.5, -1.5], [5e-4, 0.0, 0.0]))]
TOLERANCE = 1e-9


@pytest.fixture(autouse=True)
def no_pass_kept():
    """Each test starts and ends without a log's pass or its in-flight evidence kept from another."""
    dataflash_pass._passes.forget()
    in_flight_evidence._log_wide.cache_clear()
    yield
    dataflash_pass._passes.forget()
    in_flight_evidence._log_wide.cache_clear()


def posed_flight(truths: list[SensorErrors], seed: int) -> FlightLog:
    """Still poses on the ground (a calibration session of 14 orientations), then fly()'s flight: rows to
    calibrate from and a flight to leave out."""
    rng = np.random.default_rng(seed)
    motion = SyntheticImu(SensorErrors(), spread_orientations(14, rng), dwell_s=2.5, move_s=1.0,
                          rate_hz=flight_logs.RATE_HZ, seed=seed).samples()
    flight = fly(truths, seed + 1)
    ground_us = flight_logs.START_US + motion.t_ns // 1000
    shift = int(ground_us[-1] - flight.t_us[0]) + int(1e6 / flight_logs.RATE_HZ)
    raw = [(truth.raw_from_true(motion.accel_true) + rng.normal(0.0, flight_logs.NOISE_MPS2, motion.accel_true.shape))
           .astype(np.float32).astype(float) for truth in truths]
    return FlightLog(np.concatenate([ground_us, flight.t_us + shift]),
                     [np.concatenate([g, f]) for g, f in zip(raw, flight.raw)],
                     np.concatenate([motion.gyro_raw, flight.gyro]),
                     np.concatenate([np.full(len(ground_us), 30.0), flight.temperature]),
                     *(t + shift for t in (flight.arm_us, flight.liftoff_us, flight.touchdown_us, flight.disarm_us)))


def write_flight(path, seed: int, imus: int = 3) -> None:
    truths = sensors(seed, imus)
    write_dataflash_flight(path, posed_flight(truths, seed + 1), [true_in_force(t) for t in truths],
                           FILTER_BIASES[:imus], seed + 2)


def rows_of(outcome: Any) -> list[dict[str, Any]]:
    """Each row's history record and evidence, the JSON columns read as numbers."""
    found = []
    for row in (outcome, *outcome.others):
        evidence = dataclasses.asdict(row.evidence) if row.evidence is not None else None
        if evidence is not None:
            for column in ("changes", "estimator", "agreement"):
                evidence[column] = None if evidence[column] is None else json.loads(evidence[column])
        found.append({"status": row.status, "reason": row.reason, "record": dataclasses.asdict(row.record),
                      "evidence": evidence})
    return found


def assert_same(got: Any, expected: Any, where: str = "") -> None:
    """Equal, numbers within TOLERANCE (relative above 1)."""
    if isinstance(expected, dict):
        assert isinstance(got, dict) and got.keys() == expected.keys(), where
        for key in expected:
            assert_same(got[key], expected[key], f"{where}.{key}")
    elif isinstance(expected, (list, tuple)):
        assert isinstance(got, (list, tuple)) and len(got) == len(expected), where
        for k, (a, b) in enumerate(zip(got, expected)):
            assert_same(a, b, f"{where}[{k}]")
    elif isinstance(expected, float) and not isinstance(got, bool) and isinstance(got, (int, float)):
        close = abs(got - expected) <= TOLERANCE * max(1.0, abs(expected))
        assert close or (math.isnan(got) and math.isnan(expected)), (where, got, expected)
    else:
        assert got == expected, (where, got, expected)


def whole_flight_means(path: str) -> tuple[None, dict[int, int | None], dict[int, Any], Any]:
    """The in-flight means of every IMU from the log read whole, instance by instance, per sample (the
    generic read of in_flight_evidence); no pass, so the filter's records are read again too."""
    devices = accel_devices(path)
    means, flight_state = in_flight_evidence._flight_means(path, devices)
    return None, devices, means, flight_state


def read_whole(path, monkeypatch: pytest.MonkeyPatch) -> Any:
    """calibrate_recording with every IMU's samples read whole and the flight read apart: today's pass unused."""
    with monkeypatch.context() as patched:
        patched.setattr(dataflash_pass, "ground_samples", lambda *args, **kwargs: None)
        patched.setattr(in_flight_evidence, "_dataflash_flight_means", whole_flight_means)
        outcome = calibrate_recording(str(path))
    dataflash_pass._passes.forget()
    in_flight_evidence._log_wide.cache_clear()
    return outcome


@pytest.fixture(scope="module")
def three_imus(tmp_path_factory: pytest.TempPathFactory):
    path = tmp_path_factory.mktemp("pass") / "00000001.BIN"
    write_flight(path, 81)
    return path


def test_the_rows_and_the_evidence_are_those_of_the_log_read_whole(three_imus, monkeypatch):
    expected = rows_of(read_whole(three_imus, monkeypatch))
    got = rows_of(calibrate_recording(str(three_imus)))
    assert len(got) == 3 and [r["evidence"]["device"] for r in got] == [str(d) for d in ALL_DEVICES]
    for row in got:  # a calibration and evidence of each kind, not reasons, so that the comparison compares numbers
        assert row["status"] == "calibrated" and row["record"]["poses"] >= 12
        assert row["evidence"]["poses"] > 0 and row["evidence"]["changes"]
        assert row["evidence"]["estimator"]["source"].startswith("ArduPilot EKF3")
        assert "reason" not in row["evidence"]["agreement"]
    assert_same(got, expected)
    for row, bias in zip(got, FILTER_BIASES):  # the filter's settled bias, in the pass's reading of its records
        assert np.allclose(row["evidence"]["estimator"]["accel"], bias.accel_mps2, atol=0.6 * MG)


def test_a_three_imu_log_is_walked_twice(three_imus, monkeypatch):
    walks = []
    blocks = RecordReader.blocks

    def counted(reader: RecordReader) -> Any:
        walks.append(sorted(reader.names))
        return blocks(reader)

    monkeypatch.setattr(RecordReader, "blocks", counted)
    outcome = calibrate_recording(str(three_imus))
    assert [row.evidence.status for row in (outcome, *outcome.others)] == ["evidence"] * 3
    # The small types (the flight state, the filter's records) first, then the IMU records; never again.
    assert walks == [sorted(["ARM", "EV", "XKF1", "XKF2", "XKF6", "XKF7", "NKF1", "NKF2", "NKF6", "NKF7"]),
                     ["IMU", "IMU2", "IMU3"]]
    assert log_accel_devices(three_imus) == dict(enumerate(ALL_DEVICES))  # the pass says it: no walk more
    assert len(walks) == 2


@pytest.mark.parametrize("imus", [2, 3])
def test_a_log_rewritten_in_place_is_read_again(tmp_path, monkeypatch, imus):
    path = tmp_path / "00000002.BIN"
    write_flight(path, 91)
    before = rows_of(calibrate_recording(str(path)))
    mtime_ns = path.stat().st_mtime_ns
    write_flight(path, 95, imus)  # another flight at the same path: another size with 2 IMUs, the same with 3
    os.utime(path, ns=(mtime_ns + 1_000_000, mtime_ns + 1_000_000))  # its time moved on, even on a coarse clock
    again = rows_of(calibrate_recording(str(path)))
    expected = rows_of(read_whole(path, monkeypatch))
    assert_same(again, expected)
    assert len(again) == imus
    assert again[0]["record"]["bias"] != before[0]["record"]["bias"]
    assert again[0]["evidence"]["agreement"] != before[0]["evidence"]["agreement"]


def test_an_imu_whose_records_cannot_be_read_is_refused_alone(tmp_path, monkeypatch):
    """One record of IMU 1 with a TimeUS no nanosecond stamp holds: IMU 1's row fails with that reason, its
    siblings are calibrated from the same pass, and the in-flight evidence says why, as read whole."""
    path = tmp_path / "00000003.BIN"
    write_flight(path, 71)
    data = bytearray(path.read_bytes())
    imu = read_records(path, []).formats["IMU"]
    record = re.compile(b"\xa3\x95" + bytes([imu.type_id]) + b".{8}\x01", re.DOTALL).search(bytes(data))
    assert record is not None
    data[record.start() + 3:record.start() + 11] = (2**64 - 1).to_bytes(8, "little")
    path.write_bytes(bytes(data))
    got = rows_of(calibrate_recording(str(path)))
    assert [row["status"] for row in got] == ["calibrated", "failed", "calibrated"]
    assert "IMU TimeUS reaches" in got[1]["reason"] and "\n" not in got[1]["reason"]
    assert "IMU TimeUS reaches" in got[0]["evidence"]["agreement"]["reason"]
    assert_same(got, rows_of(read_whole(path, monkeypatch)))
