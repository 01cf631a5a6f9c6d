"""export --to ardupilot / px4 of a warm-up's calibration: INS_TCALn_* with the accelerometer's and the gyro's cubic
(ENABLE, TMIN, TMAX, ACC1..3, GYR1..3, 35 degC reference, zero at INS_ACCn_CALTEMP / INS_GYRn_CALTEMP), checked
by applying ArduPilot's own formula (TCal::correct_sensor) to the raw samples of the simulated sensor."""
from __future__ import annotations

import re

import numpy as np

from accel_calibration.cli.main import main
from accel_calibration.core.units import MG, STANDARD_GRAVITY

from helpers.autopilot_logs import DEVICES, ardupilot_parameters, write_ardupilot_log, write_px4_log
from helpers.warmup_sessions import ardupilot_applied, px4_applied, read_params, read_px4_params, warmup_board


def half_peak_to_peak(values: np.ndarray) -> float:
    """A temperature error free of the constant the offsets hold (ArduPilot recomputes the gyro's at boot)."""
    return float(np.max(np.ptp(values, axis=0)) / 2)


def time_weighted_cubic_params(board, instance: int) -> dict[str, float]:
    """The autopilots' approach as the baseline: a cubic per axis in T - 35 over every raw sample (weighted
    by time), written as ArduPilot holds it (zero at TMIN, which CALTEMP is clamped to)."""
    imu = board.imus[instance]
    low, high = float(board.temperature.min()), float(board.temperature.max())
    n = instance + 1
    params = {f"INS_TCAL{n}_ENABLE": 1.0, f"INS_TCAL{n}_TMIN": low, f"INS_TCAL{n}_TMAX": high}
    for kind, values in (("ACC", imu.raw), ("GYR", imu.gyro_raw)):
        coefficients = np.polynomial.polynomial.polyfit(board.temperature - 35.0, values, 3)
        for k in (1, 2, 3):
            for axis, name in enumerate("XYZ"):
                params[f"INS_TCAL{n}_{kind}{k}_{name}"] = float(coefficients[k, axis]) * 1e6
    return params


def test_the_ardupilot_export_of_a_warm_up_holds_both_drifts_within_its_stated_loss(tmp_path, capsys):
    board, truths = warmup_board(35)
    write_ardupilot_log(tmp_path / "warm.bin", board)
    vehicle = ardupilot_parameters(board)
    degc = np.linspace(float(board.temperature.min()), float(board.temperature.max()), 300)
    for instance, truth in enumerate(truths):
        cal, param = tmp_path / f"imu{instance}.yaml", tmp_path / f"imu{instance}.param"
        assert main(["replay", str(tmp_path / "warm.bin"), "--warmup", "--instance", str(instance),
                     "-o", str(cal)]) == 0
        code = main(["export", str(cal), "--to", "ardupilot", "--instance", str(instance), "--max-loss-mg", "3",
                     "-o", str(param)])
        printed, err = capsys.readouterr()
        assert code == 0, err
        exported = read_params(param)
        n = instance + 1
        assert exported[f"INS_TCAL{n}_ENABLE"] == 1
        assert exported[f"INS_GYR{n}_CALTEMP"] == exported[f"INS_ACC{n}_CALTEMP"]
        # TMIN, TMAX inside the warm-up's range where ArduPilot's clamp follows the curve's levelling off
        assert 15.0 <= exported[f"INS_TCAL{n}_TMIN"] < exported[f"INS_TCAL{n}_TMAX"] <= 45.0
        if exported[f"INS_TCAL{n}_TMIN"] > 15.5 or exported[f"INS_TCAL{n}_TMAX"] < 44.0:
            assert "ArduPilot holds the correction flat beyond them" in printed
        assert all(f"INS_TCAL{n}_GYR{k}_{a}" in exported for k in (1, 2, 3) for a in "XYZ")
        stated_mg = float(re.search(r"bias drift polynomial: worst ([0-9.]+) mg", printed).group(1))
        stated = float(re.search(r"gyro drift as a cubic .*: worst ([0-9.]+) mrad/s from ours", printed).group(1))
        # ArduPilot's formula on the raw output of the sensor at rest across the range
        still = np.linalg.solve(truth.calibration.matrix, [0.0, 0.0, STANDARD_GRAVITY]) + truth.calibration.bias
        raw, gyro_raw = still + truth.accel_drift(degc), truth.calibration.gyro_bias_radps + truth.gyro_drift(degc)
        accel, gyro = ardupilot_applied({**vehicle, **exported}, instance, raw, gyro_raw, degc)
        accel_mg, gyro_mradps = half_peak_to_peak(accel) / MG, half_peak_to_peak(gyro) * 1e3
        # within what export said it loses (a cubic cannot follow the tanh-shaped truth) and our own fit's error
        assert accel_mg <= stated_mg + 0.5 and gyro_mradps <= stated + 0.1
        assert accel_mg <= 2.0 and gyro_mradps <= 0.45
        # the time-weighted cubic of the same samples, applied alike, is further off
        baseline = {**vehicle, **time_weighted_cubic_params(board, instance)}
        cubic_accel, cubic_gyro = ardupilot_applied(baseline, instance, raw, gyro_raw, degc)
        assert half_peak_to_peak(cubic_accel) / MG > 2 * accel_mg
        assert half_peak_to_peak(cubic_gyro) > 1.2 * gyro_mradps * 1e-3


def test_the_px4_export_of_a_warm_up_holds_both_drifts_in_tc_a_and_tc_g(tmp_path, capsys):
    board, truths = warmup_board(37)
    write_px4_log(tmp_path / "warm.ulg", board)
    degc = np.linspace(float(board.temperature.min()), float(board.temperature.max()), 300)
    for instance, truth in enumerate(truths):
        cal, param = tmp_path / f"imu{instance}.yaml", tmp_path / f"imu{instance}.params"
        assert main(["replay", str(tmp_path / "warm.ulg"), "--warmup", "--instance", str(instance),
                     "-o", str(cal)]) == 0
        code = main(["export", str(cal), "--to", "px4", "--instance", str(instance), "--max-loss-mg", "3",
                     "-o", str(param)])
        printed, err = capsys.readouterr()
        assert code == 0, err
        exported = read_px4_params(param)
        assert exported["TC_A_ENABLE"] == 1 and exported["TC_G_ENABLE"] == 1
        assert exported[f"TC_G{instance}_ID"] == exported[f"CAL_GYRO{instance}_ID"] == DEVICES[instance]
        stated = float(re.search(r"px4 holds the gyro drift as a cubic .*: worst ([0-9.]+) mrad/s", printed).group(1))
        still = np.linalg.solve(truth.calibration.matrix, [0.0, 0.0, STANDARD_GRAVITY]) + truth.calibration.bias
        raw, gyro_raw = still + truth.accel_drift(degc), truth.calibration.gyro_bias_radps + truth.gyro_drift(degc)
        accel, gyro = px4_applied(exported, instance, raw, gyro_raw, degc)
        accel_mg, gyro_mradps = half_peak_to_peak(accel) / MG, half_peak_to_peak(gyro) * 1e3
        assert accel_mg <= 2.0 and gyro_mradps <= stated + 0.1 and gyro_mradps <= 0.45
        # PX4 does not recompute the gyro offset at boot: the gyro's whole output is its error
        assert np.abs(gyro).max() * 1e3 <= 0.6
