"""The history of flight evidence: per IMU (by its device) a series of its flights' ground evidence,
judged by check's change rule with the scatter between flights measured from the series. Simulated
fleets with known truth (the per-flight evidence simulated, helpers/flight_series.py): steady IMUs over
100 flights give no flag, a 0.2 mg/flight drift is flagged within 25 flights of crossing 3 mg, a 5 mg step
at the first flight after it, naming the IMU by its device; on SQLite and PostgreSQL alike."""
from __future__ import annotations

import numpy as np
import pytest

from accel_calibration.cli.main import main
from accel_calibration.core.evidence_trend import MIN_FLIGHTS, first_flagged, trend
from accel_calibration.core.units import MG
from accel_calibration.io.history import open_history

from helpers.flight_series import SIGMA_MPS2, rows, z_series

FLIGHTS = 100
SEEDS = range(12)


def sigmas(n):
    return np.full(n, SIGMA_MPS2)


@pytest.mark.parametrize("seed", SEEDS)
def test_steady_imus_over_100_flights_are_never_flagged_as_flights_arrive(seed):
    z = z_series(seed, FLIGHTS)
    assert first_flagged(z, sigmas(FLIGHTS)) is None


@pytest.mark.parametrize("seed", SEEDS)
def test_a_drift_of_0_2_mg_per_flight_is_flagged_within_25_flights_of_crossing_3_mg(seed):
    z = z_series(seed, FLIGHTS, drift_mg_per_flight=0.2, drift_from=30)
    crossing = 30 + 15  # the 15th drifting flight is 3 mg off
    flagged = first_flagged(z, sigmas(FLIGHTS))
    assert flagged is not None and flagged <= crossing + 25


@pytest.mark.parametrize("seed", SEEDS)
def test_a_5_mg_step_is_flagged_at_the_first_flight_after_it(seed):
    z = z_series(seed, FLIGHTS, step_mg=5.0, step_at=40)
    assert first_flagged(z, sigmas(FLIGHTS)) == 41  # flights 0..40: the 41st is the first stepped one
    judged = trend(z[:41], sigmas(41))
    assert judged.since == 40 and abs(judged.change - 5 * MG) < 2.5 * SCATTER_MG * MG


SCATTER_MG = 0.5


def test_too_few_flights_cannot_tell():
    judged = trend(z_series(1, MIN_FLIGHTS - 1), sigmas(MIN_FLIGHTS - 1))
    assert judged.status == "cannot tell" and "10 needed" in judged.reason


def write_fleet(target):
    """uav07: IMU 1 steady, IMU 2 steps 5 mg at its 71st flight; uav08: both steady (100 flights each)."""
    with open_history(target) as history:
        history.write_evidence(rows("uav07", 0, z_series(1, FLIGHTS)) +
                               rows("uav07", 1, z_series(2, 71, step_mg=5.0, step_at=70)) +
                               rows("uav08", 0, z_series(3, FLIGHTS)) + rows("uav08", 1, z_series(4, FLIGHTS)))


def assert_history_names_the_stepped_imu(target, capsys):
    capsys.readouterr()
    assert main(["history", "--history", target]) == 3
    out = capsys.readouterr().out.splitlines()
    moved = [line.strip() for line in out if line.strip().endswith(": recalibrate")]
    assert len(moved) == 1
    assert moved[0].startswith("vehicle uav07 IMU 2 (device 1442060): bias z or scale z +")
    assert moved[0].endswith("mg at 1 g over 1 flight (" + moved[0].split("(")[2].split(")")[0] +
                             "), since flight 2027-01-11T10:14: recalibrate")
    change_mg = float(moved[0].split("scale z ")[1].split(" mg")[0])
    assert abs(change_mg - 5.0) < 1.5
    holds = [line for line in out if ": holds: " in line]
    assert len(holds) == 3
    assert main(["history", "--history", target, "--vehicle", "uav08"]) == 0


def test_history_exits_3_naming_the_imu_by_its_device_and_0_when_all_hold(tmp_path, capsys):
    target = str(tmp_path / "fleet.sqlite")
    write_fleet(target)
    assert_history_names_the_stepped_imu(target, capsys)


def test_history_on_postgresql_names_the_same_imu(pg_url, capsys):
    write_fleet(pg_url)
    with open_history(pg_url) as history:  # a rewrite updates the same rows
        history.write_evidence(rows("uav08", 0, z_series(3, FLIGHTS)))
        assert len(history.evidence()) == 3 * FLIGHTS + 71
    assert_history_names_the_stepped_imu(pg_url, capsys)


def test_history_cannot_tell_with_too_few_flights(tmp_path, capsys):
    target = str(tmp_path / "few.sqlite")
    with open_history(target) as history:
        history.write_evidence(rows("uav09", 0, z_series(5, 6)))
    assert main(["history", "--history", target]) == 1
    assert "vehicle uav09 IMU 1 (device 1310988): cannot tell: 6 flights with evidence" in capsys.readouterr().out


def test_a_recalibration_restarts_the_series(tmp_path, capsys):
    """The step is the vehicle recalibrated: its calibration in force changed at the same flight, so the
    flights since are judged alone (too few yet: cannot tell), not flagged against the old ones."""
    import dataclasses

    series = rows("uav10", 0, z_series(6, 40, step_mg=5.0, step_at=35))
    series = series[:35] + [dataclasses.replace(r, in_force=r.in_force + " recalibrated") for r in series[35:]]
    target = str(tmp_path / "recalibrated.sqlite")
    with open_history(target) as history:
        history.write_evidence(series)
    assert main(["history", "--history", target]) == 1
    assert "IMU 1 (device 1310988): cannot tell: 5 flights with evidence" in capsys.readouterr().out


def test_an_evidence_row_another_program_wrote_off_the_schema_is_left_out_and_said(tmp_path, capsys):
    """SQLite keeps text in a REAL column: such a row is left out with one warning line, the rest judged."""
    import sqlite3

    target = tmp_path / "hostile.sqlite"
    write_fleet(str(target))
    with sqlite3.connect(target) as connection:
        connection.execute("UPDATE flight_evidence SET z_mps2 = 'lots' WHERE rowid = "
                           "(SELECT rowid FROM flight_evidence WHERE vehicle = 'uav08' LIMIT 1)")
        connection.execute("UPDATE flight_evidence SET estimator = '{not json' WHERE rowid = "
                           "(SELECT rowid FROM flight_evidence WHERE vehicle = 'uav08' LIMIT 1 OFFSET 1)")
    capsys.readouterr()
    assert main(["history", "--history", str(target), "--vehicle", "uav08"]) == 0
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    warnings = [line for line in captured.err.splitlines() if "accel-calib: warning:" in line]
    assert len(warnings) == 1 and "2 flight evidence rows" in warnings[0], captured.err
    assert len([line for line in captured.out.splitlines() if ": holds: " in line]) == 2
