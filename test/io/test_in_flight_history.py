"""The in-flight evidence over flights, per IMU: the autopilot filter's settled bias and the IMU's agreement
with its siblings, stored beside the ground evidence (one row per vehicle, IMU and flight) and judged per axis
by the same change detector (core/evidence_trend.py). Simulated series with known truth
(helpers/flight_series.py): steady IMUs are never flagged, a bias the filter keeps learning is, an IMU that
disagrees with its siblings is named by its device; a history written before these columns still reads."""
from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from accel_calibration.cli.main import main
from accel_calibration.core.evidence_trend import MAX_GYRO_BIAS_CHANGE_RADPS, first_flagged, trend
from accel_calibration.core.units import MG
from accel_calibration.io.flight_history import imu_series
from accel_calibration.io.history import open_history

from helpers.flight_series import (
    AGREEMENT_SCATTER_MPS2,
    AGREEMENT_SIGMA_MPS2,
    ESTIMATOR_SCATTER_MPS2,
    ESTIMATOR_SIGMA_MPS2,
    axis_series,
    rows,
    with_in_flight,
    z_series,
)

FLIGHTS = 30
DRIFT_MG = 0.3  # per flight, from DRIFT_FROM
DRIFT_FROM = 10
STEP_MG, STEP_AT = 3.0, 20


def estimator(seed, flights=FLIGHTS, **change):
    return axis_series(seed, flights, ESTIMATOR_SIGMA_MPS2, ESTIMATOR_SCATTER_MPS2, **change)


def agreeing(seed, flights=FLIGHTS, **change):
    return axis_series(seed, flights, AGREEMENT_SIGMA_MPS2, AGREEMENT_SCATTER_MPS2, **change)


def imu_rows(vehicle, imu, seed, flights=FLIGHTS, estimated=None, agreement=None, siblings=2):
    return with_in_flight(rows(vehicle, imu, z_series(seed, flights)),
                          estimator(seed + 100, flights) if estimated is None else estimated,
                          agreeing(seed + 200, flights) if agreement is None else agreement,
                          siblings=siblings, seed=seed)


@pytest.mark.parametrize("seed", range(12))
def test_steady_in_flight_evidence_over_100_flights_is_never_flagged(seed):
    series = imu_series(imu_rows("uav01", 0, seed, 100))
    (imu,) = series
    assert [k.kind for k in imu.in_flight] == ["estimator", "agreement"]
    assert imu.status == "holds", imu.said_in_flight()


def write_fleet(target):
    """uav07: steady; uav08: IMU 2's filter learns a z bias growing 0.3 mg a flight from flight 11; uav09: IMU 3
    steps 3 mg from its siblings at flight 21 (its siblings then agree with each other: their best match)."""
    with open_history(target) as history:
        fleet = [r for imu in range(3) for r in imu_rows("uav07", imu, 10 + imu)]
        fleet += [r for imu in range(3) for r in imu_rows(
            "uav08", imu, 20 + imu, estimated=estimator(120 + imu, change_per_flight=DRIFT_MG * MG * (imu == 1),
                                                        change_from=DRIFT_FROM))]
        fleet += [r for imu in range(3) for r in imu_rows(
            "uav09", imu, 30 + imu, agreement=agreeing(230 + imu, step=STEP_MG * MG * (imu == 2), step_at=STEP_AT))]
        history.write_evidence(fleet)


def test_history_names_a_bias_the_filter_keeps_learning_and_an_imu_that_disagrees(tmp_path, capsys):
    target = str(tmp_path / "fleet.sqlite")
    write_fleet(target)
    capsys.readouterr()
    assert main(["history", "--history", target]) == 3
    out = [line.strip() for line in capsys.readouterr().out.splitlines()]
    moved = [line for line in out if line.endswith(": recalibrate")]
    assert len(moved) == 2, moved
    learning, disagreeing = moved
    assert learning.startswith("vehicle uav08 IMU 2 (device 1442060): the filter keeps learning a bias: accel bias z +")
    assert disagreeing.startswith("vehicle uav09 IMU 3 (device 3801122) disagrees with its siblings: accel z +")
    step = float(disagreeing.split("accel z ")[1].split(" mg")[0])
    assert abs(step - STEP_MG) < 0.5
    first_after = rows("uav09", 2, z_series(32, FLIGHTS))[STEP_AT].flight
    assert f"since flight {first_after}: " in disagreeing  # the first flight after the step
    assert main(["history", "--history", target, "--vehicle", "uav07"]) == 0


def test_a_growing_filter_bias_is_flagged_within_flights_of_its_start():
    """As flights arrive: the z bias the filter learns grows 0.3 mg a flight from flight 11 (a scatter between
    flights of 0.5 mg): flagged within 5 flights of having grown 3 mg, in every seed (measured: 8..14 flights
    after its start, 2.4..4.2 mg grown)."""
    flagged = []
    for seed in range(12):
        values = estimator(300 + seed, 40, change_per_flight=DRIFT_MG * MG, change_from=DRIFT_FROM)[:, 2]
        at = first_flagged(values, np.full(len(values), ESTIMATOR_SIGMA_MPS2))
        assert at is not None
        flagged.append(at - DRIFT_FROM)
    assert max(flagged) <= round(3.0 / DRIFT_MG) + 5, flagged


def test_with_two_imus_either_may_have_moved(tmp_path):
    moving = agreeing(40, step=STEP_MG * MG, step_at=STEP_AT)
    series = imu_series(imu_rows("uav10", 1, 41, agreement=moving, siblings=1))
    (line,) = [s for s in series[0].said_in_flight() if "recalibrate" in s]
    assert line.startswith("vehicle uav10 IMU 2 (device 1442060) disagrees with IMU 1 (device 1310988), its only "
                           "sibling (either may have moved): accel z +")


def test_a_gyro_series_is_judged_against_its_own_plausibility_bound():
    """Sigmas large enough to excuse anything: the gyro's bound (3 deg/s) flags a 4 deg/s step; the
    accelerometer's 50 mg, read in rad/s, would not."""
    values = np.concatenate([np.zeros(10), np.full(5, np.radians(4.0))])
    sigmas = np.full(15, np.radians(10.0))
    assert trend(values, sigmas, bound=MAX_GYRO_BIAS_CHANGE_RADPS).status == "moved"
    assert trend(values, sigmas).status == "holds"


def test_a_history_written_before_the_in_flight_columns_reads_and_gains_them(tmp_path, capsys):
    """A history whose flight_evidence table has no in-flight columns (as written before they were added):
    read-only commands read its rows; the next fleet run adds the columns and writes them."""
    target = tmp_path / "old.sqlite"
    with open_history(str(target)) as history:
        history.write_evidence(rows("uav11", 0, z_series(50, 12)))
    with sqlite3.connect(target) as connection:  # the table as it was before the in-flight columns
        connection.execute("ALTER TABLE flight_evidence DROP COLUMN estimator")
        connection.execute("ALTER TABLE flight_evidence DROP COLUMN agreement")
    assert main(["history", "--history", str(target)]) == 0
    assert "vehicle uav11 IMU 1 (device 1310988): holds: 12 flights" in capsys.readouterr().out
    with open_history(str(target)) as history:
        history.write_evidence(imu_rows("uav11", 1, 51, 12))
        found = history.evidence()
    assert len(found) == 24
    assert sum(r.estimator is not None for r in found) == 12
    with sqlite3.connect(target) as connection:
        columns = {row[1] for row in connection.execute("PRAGMA table_info(flight_evidence)")}
    assert {"estimator", "agreement"} <= columns


def test_nan_in_the_in_flight_evidence_is_stored_as_null(tmp_path):
    import dataclasses
    import json

    (record,) = rows("uav12", 0, z_series(60, 1))
    record = dataclasses.replace(record, estimator=json.dumps({"accel": [float("nan"), None, 0.01]}))
    target = str(tmp_path / "nan.sqlite")
    with open_history(target) as history:
        history.write_evidence([record])
        (back,) = history.evidence()
    assert json.loads(back.estimator) == {"accel": [None, None, 0.01]}
    assert "NaN" not in back.estimator


def test_a_postgresql_history_written_before_gains_the_columns_and_says_the_same(pg_url, tmp_path, capsys):
    from sqlalchemy import create_engine, text

    with open_history(pg_url) as history:
        history.write_evidence(rows("uav11", 0, z_series(50, 12)))
    engine = create_engine(pg_url.replace("postgresql://", "postgresql+psycopg://", 1))
    with engine.begin() as connection:  # the table as it was before the in-flight columns
        connection.execute(text("ALTER TABLE flight_evidence DROP COLUMN estimator, DROP COLUMN agreement"))
    engine.dispose()
    assert main(["history", "--history", pg_url]) == 0
    assert "vehicle uav11 IMU 1 (device 1310988): holds: 12 flights" in capsys.readouterr().out
    write_fleet(pg_url)
    sqlite = str(tmp_path / "same.sqlite")
    write_fleet(sqlite)
    with open_history(sqlite) as history:
        history.write_evidence(rows("uav11", 0, z_series(50, 12)))
    said = []
    for target in (pg_url, sqlite):
        assert main(["history", "--history", target]) == 3
        said.append(capsys.readouterr().out)
    assert said[0] == said[1]
