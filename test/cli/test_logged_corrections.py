"""Autopilot logs carry corrected streams (ArduPilot IMU records, PX4 sensor_combined): replay undoes the
correction the log's own parameters describe, so the calibration written corrects the RAW sensor in its
own axes. End to end through the CLI on simulated logs in the real formats (two IMUs, known raw errors,
a stale calibration in the parameters, a 90 deg yaw board rotation): replay -> export per IMU -> the
exported parameters applied with each autopilot's own formula (re-implemented here from its source) to
the raw samples -> the truth."""
from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from accel_calibration.cli.main import main
from accel_calibration.io.autopilot_params import parse_parameter_text
from accel_calibration.io.calibration_file import load_calibration
from msg_tools.dataflash_writer import FORMATS_4X, imu_records, parameter_records, write_dataflash
from msg_tools.ulog_writer import sensor_combined_array, sensor_selection_array, sensor_triplet_array, write_ulog

from helpers.autopilot_logs import (
    DEVICES,
    MG,
    START_US,
    YAW_90,
    Imu,
    ardupilot_parameters,
    logged,
    simulate,
    write_ardupilot_log,
    write_px4_log,
)


def ardupilot_correct(params: dict[str, float], instance: int, raw: np.ndarray) -> np.ndarray:
    """AP_InertialSensor_Backend::_rotate_and_correct_accel before the board rotation: accel -= INS_ACC*OFFS,
    then *= INS_ACC*SCAL per axis (no temperature calibration here)."""
    n = "" if instance == 0 else str(instance + 1)
    offset = np.array([params[f"INS_ACC{n}OFFS_{a}"] for a in "XYZ"])
    scale = np.array([params[f"INS_ACC{n}SCAL_{a}"] for a in "XYZ"])
    return (raw - offset) * scale


def px4_correct(params: dict[str, float], instance: int, raw: np.ndarray) -> np.ndarray:
    """calibration::Accelerometer::Correct before the rotation: (raw - CAL_ACCn_OFF) .* CAL_ACCn_SCALE."""
    offset = np.array([params[f"CAL_ACC{instance}_{a}OFF"] for a in "XYZ"])
    scale = np.array([params[f"CAL_ACC{instance}_{a}SCALE"] for a in "XYZ"])
    return (raw - offset) * scale


def worst_error_mg(corrected: np.ndarray, imu: Imu) -> float:
    true = (imu.raw - imu.truth.bias_mps2) @ imu.truth.matrix.T  # the truth applied to the same raw samples
    return float(np.max(np.linalg.norm(corrected - true, axis=1)) / MG)


def replay_and_export(log, tmp_path, target: str, instance: int, replay_args: list[str], capsys
                      ) -> tuple[dict[str, float], str, float]:
    """(exported parameters, replay's output, the loss export states in mg)."""
    calibration = tmp_path / f"{target}{instance}.yaml"
    assert main(["replay", str(log), *replay_args, "-o", str(calibration)]) == 0
    said = capsys.readouterr().out
    exported = tmp_path / f"{target}{instance}.param"
    assert main(["export", str(calibration), "--to", target, "--instance", str(instance), "--force",
                 "-o", str(exported)]) == 0
    stated = float(re.search(r"worst ([0-9.]+) mg", capsys.readouterr().out).group(1))
    return parse_parameter_text(exported.read_text(), str(exported)).values, said, stated


@pytest.mark.parametrize("old_style", [False, True], ids=["IMU with I", "IMU and IMU2"])
def test_ardupilot_export_corrects_the_raw_sensor(tmp_path, capsys, old_style):
    board = simulate(7)
    log = tmp_path / "00000042.BIN"
    write_ardupilot_log(log, board, old_style)
    for k, imu in enumerate(board.imus):
        params, said, stated = replay_and_export(log, tmp_path, "ardupilot", k, ["--instance", str(k)], capsys)
        error = worst_error_mg(ardupilot_correct(params, k, imu.raw), imu)
        assert error < 0.5, f"IMU {k}: {error:.2f} mg"
        assert stated < 0.5  # a diagonal truth: the autopilot holds it whole (sphere9 sees a little noise)
        assert "fitted to raw: DataFlash IMU instance" in said and "AHRS_ORIENTATION 2" in said
        # The gyro's offsets too: ArduPilot subtracts INS_GYR*OFFS before the board rotation.
        n = "" if k == 0 else str(k + 1)
        gyro_offset = np.array([params[f"INS_GYR{n}OFFS_{a}"] for a in "XYZ"])
        assert np.max(np.abs(gyro_offset - imu.gyro_bias)) < 3e-4
        assert "raw: " in load_calibration(tmp_path / f"ardupilot{k}.yaml").fitted_to


def test_px4_export_corrects_the_raw_sensor_from_combined_and_from_sensor_accel(tmp_path, capsys):
    board = simulate(8)
    log = tmp_path / "bench.ulg"
    write_px4_log(log, board)
    # sensor_combined (corrected by CAL_ACC0 and SENS_BOARD_ROT, undone), then IMU 1's own sensor_accel.
    for k, args in ((0, []), (1, ["--instance", "1"])):
        params, said, stated = replay_and_export(log, tmp_path, "px4", k, args, capsys)
        error = worst_error_mg(px4_correct(params, k, board.imus[k].raw), board.imus[k])
        assert error < 0.5, f"IMU {k}: {error:.2f} mg"
        assert stated < 0.5
        assert ("SENS_BOARD_ROT 2" in said) if k == 0 else (f"fitted to raw: sensor_accel instance 1 (px4 device "
                                                            f"{DEVICES[1]})" in said)


def test_a_misaligned_truth_is_within_the_stated_loss(tmp_path, capsys):
    board = simulate(9, misaligned=True)
    log = tmp_path / "misaligned.bin"
    write_ardupilot_log(log, board)
    params, _, stated = replay_and_export(log, tmp_path, "ardupilot", 1, ["--instance", "1", "--model", "sphere9"],
                                          capsys)
    error = worst_error_mg(ardupilot_correct(params, 1, board.imus[1].raw), board.imus[1])
    assert stated > 5  # ~1 deg of non-orthogonality the autopilot cannot hold
    assert error < stated + 0.5


def test_a_rotation_the_reader_does_not_know_is_one_line(tmp_path, capsys):
    board = simulate(7)
    log = tmp_path / "custom.bin"
    records = parameter_records(START_US - 1000, {**ardupilot_parameters(board), "AHRS_ORIENTATION": 101.0})
    accel, gyro = logged(board.imus[0])
    write_dataflash(log, FORMATS_4X, records + imu_records(board.t_us[:50], accel[:50], gyro[:50],
                                                           board.temperature[:50]))
    out = tmp_path / "cal.yaml"
    assert main(["replay", str(log), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "AHRS_ORIENTATION = 101 is not a rotation" in err
    assert not out.exists()


def test_the_rotation_table_matches_the_autopilots_rotate():
    from accel_calibration.bag.logged_correction import rotation_matrix

    v = np.array([1.0, 2.0, 3.0])
    # rotate_3f / Vector3::rotate: YAW_90 (x, y) -> (-y, x); ROLL_180 (y, z) -> (-y, -z); PITCH_90 (x, z) -> (z, -x)
    np.testing.assert_allclose(rotation_matrix(2) @ v, [-2.0, 1.0, 3.0], atol=1e-12)
    np.testing.assert_allclose(rotation_matrix(8) @ v, [1.0, -2.0, -3.0], atol=1e-12)
    np.testing.assert_allclose(rotation_matrix(24) @ v, [3.0, 2.0, -1.0], atol=1e-12)
    assert Rotation.from_matrix(rotation_matrix(17)).magnitude() > 0


def ardupilot_tcal(params: dict[str, float], instance: int, temperature: np.ndarray) -> np.ndarray:
    """AP_InertialSensor::TCal::correct_sensor's offset: P(clamp(T) - 35) - P(clamp(CALTEMP) - 35),
    P(d) = (c1 + (c2 + c3 d) d) d * 1e-6, clamped to TMIN..TMAX (what v -= ... subtracts)."""
    n = instance + 1
    low, high = params[f"INS_TCAL{n}_TMIN"], params[f"INS_TCAL{n}_TMAX"]
    c = [np.array([params[f"INS_TCAL{n}_ACC{k}_{a}"] for a in "XYZ"]) for k in (1, 2, 3)]

    def polynomial(d):
        d = d[:, None]
        return (c[0] + (c[1] + c[2] * d) * d) * d * 1e-6

    at = polynomial(np.clip(temperature, low, high) - 35.0)
    return at - polynomial(np.clip(np.array([params[f"INS_ACC{n}_CALTEMP"]]), low, high) - 35.0)


def test_an_ardupilot_temperature_calibration_is_undone_at_each_samples_temperature(tmp_path, capsys):
    board = simulate(13)
    board.temperature = np.linspace(18.0, 47.0, len(board.t_us))  # warming through the session
    params = {**ardupilot_parameters(board), "INS_TCAL1_ENABLE": 1.0, "INS_TCAL1_TMIN": 20.0,
              "INS_TCAL1_TMAX": 45.0, "INS_ACC1_CALTEMP": 30.0}
    for k, coefficient in enumerate((20000.0, -40.0, 2.0), start=1):  # tens of mg across the range
        for a, sign in zip("XYZ", (1.0, -0.5, 0.8)):
            params[f"INS_TCAL1_ACC{k}_{a}"] = coefficient * sign
    imu = board.imus[0]
    accel, gyro = logged(imu)
    thermal = ardupilot_tcal(params, 0, board.temperature)
    accel = accel - (thermal * imu.stale_scale) @ YAW_90.T  # R ((x - tcal(T) - offset) * scale)
    assert np.ptp(thermal, axis=0).max() / MG > 20
    log = tmp_path / "warm.bin"
    write_dataflash(log, FORMATS_4X, parameter_records(START_US - 1000, params)
                    + imu_records(board.t_us, accel, gyro, board.temperature))
    exported, said, _ = replay_and_export(log, tmp_path, "ardupilot", 0, [], capsys)
    assert "INS_TCAL1" in said
    assert worst_error_mg(ardupilot_correct(exported, 0, imu.raw), imu) < 0.5


def test_a_px4_thermal_offset_without_a_temperature_is_one_line(tmp_path, capsys):
    board = simulate(14)
    accel, gyro = logged(board.imus[0])
    params = {"SENS_BOARD_ROT": 2, "TC_A_ENABLE": 1, "TC_A0_ID": DEVICES[0], "TC_A0_TREF": 25.0,
              "TC_A0_TMIN": 0.0, "TC_A0_TMAX": 60.0, "TC_A0_X1_0": 0.001, "CAL_ACC0_ID": DEVICES[0],
              **{f"CAL_ACC0_{a}OFF": 0.1 for a in "XYZ"}, **{f"CAL_ACC0_{a}SCALE": 1.0 for a in "XYZ"}}
    log = tmp_path / "no_temperature.ulg"
    write_ulog(log, [("sensor_combined", 0, sensor_combined_array(board.t_us, accel, gyro)),
                     ("sensor_selection", 0, sensor_selection_array(board.t_us[::100], DEVICES[0], DEVICES[0]))],
               parameters=params)
    out = tmp_path / "cal.yaml"
    assert main(["replay", str(log), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "thermal compensation is enabled but the log gives no temperature" in err
    assert not out.exists()


# --- the vehicle's own thermal compensation: the export switches it off --------------------------------------

def px4_thermal_offset(params: dict[str, float], slot: int, temperature: np.ndarray) -> np.ndarray:
    """TemperatureCompensation::calc_thermal_offsets_3D: X0 + X1 dT + X2 dT^2 + X3 dT^3,
    dT = clamp(T, TMIN, TMAX) - TREF."""
    tc = f"TC_A{slot}_"
    d = (np.clip(temperature, params[tc + "TMIN"], params[tc + "TMAX"]) - params[tc + "TREF"])[:, None]
    x = [np.array([params.get(f"{tc}X{p}_{i}", 0.0) for i in range(3)]) for p in range(4)]
    return x[0] + (x[1] + (x[2] + x[3] * d) * d) * d


def px4_vehicle(params: dict[str, float], instance: int, raw: np.ndarray, temperature: np.ndarray) -> np.ndarray:
    """What PX4 makes of the raw samples with these parameters in force: the thermal offset of the TC_Aj slot
    whose TC_Aj_ID is CAL_ACCn_ID where TC_A_ENABLE is 1, then (x - CAL_ACCn_OFF) .* CAL_ACCn_SCALE."""
    if params.get("TC_A_ENABLE", 0) == 1:
        for slot in range(4):
            if f"TC_A{slot}_TREF" in params and params.get(f"TC_A{slot}_ID") == params[f"CAL_ACC{instance}_ID"]:
                raw = raw - px4_thermal_offset(params, slot, temperature)
                break
    return px4_correct(params, instance, raw)


def ardupilot_vehicle(params: dict[str, float], instance: int, raw: np.ndarray, temperature: np.ndarray
                      ) -> np.ndarray:
    """What ArduPilot makes of the raw samples with these parameters in force: TCal::correct_sensor where
    INS_TCALn_ENABLE is 1, then the offsets and scales."""
    if params.get(f"INS_TCAL{instance + 1}_ENABLE", 0) == 1:
        raw = raw - ardupilot_tcal(params, instance, temperature)
    return ardupilot_correct(params, instance, raw)


def test_an_ardupilot_export_switches_off_the_temperature_calibration_it_undid(tmp_path, capsys):
    """The vehicle's parameters (the log's) overlaid by the export, applied as ArduPilot applies them: the
    truth within the stated loss; the vehicle's INS_TCAL1 left on cost 2.6 mg."""
    board = simulate(13)
    board.temperature = np.linspace(18.0, 47.0, len(board.t_us))
    vehicle = {**ardupilot_parameters(board), "INS_TCAL1_ENABLE": 1.0, "INS_TCAL1_TMIN": 20.0,
               "INS_TCAL1_TMAX": 45.0, "INS_ACC1_CALTEMP": 30.0}
    for k, coefficient in enumerate((20000.0, -40.0, 2.0), start=1):
        for a, sign in zip("XYZ", (1.0, -0.5, 0.8)):
            vehicle[f"INS_TCAL1_ACC{k}_{a}"] = coefficient * sign
    imu = board.imus[0]
    accel, gyro = logged(imu)
    accel = accel - (ardupilot_tcal(vehicle, 0, board.temperature) * imu.stale_scale) @ YAW_90.T
    log = tmp_path / "warm.bin"
    write_dataflash(log, FORMATS_4X, parameter_records(START_US - 1000, vehicle)
                    + imu_records(board.t_us, accel, gyro, board.temperature))
    exported, _, stated = replay_and_export(log, tmp_path, "ardupilot", 0, [], capsys)
    assert exported["INS_TCAL1_ENABLE"] == 0
    loaded = {**vehicle, **exported}
    error = worst_error_mg(ardupilot_vehicle(loaded, 0, imu.raw, board.temperature), imu)
    assert error < stated + 0.5, f"{error:.2f} mg, stated {stated:.2f} mg"


def test_a_px4_export_switches_off_the_thermal_compensation_it_undid(tmp_path, capsys):
    """As for ArduPilot: PX4's TC_A left on, the export loaded over it cost 5.5 mg; TC_A_ENABLE is one switch
    for every accelerometer, and the export says so."""
    board = simulate(14)
    board.temperature = np.linspace(15.0, 50.0, len(board.t_us))
    imu = board.imus[0]
    vehicle = {"SENS_BOARD_ROT": 2, "TC_A_ENABLE": 1, "TC_G_ENABLE": 0, "TC_A0_ID": DEVICES[0], "TC_A0_TREF": 25.0,
               "TC_A0_TMIN": 10.0, "TC_A0_TMAX": 55.0, "CAL_ACC0_ID": DEVICES[0], "CAL_GYRO0_ID": DEVICES[0]}
    for i, (x1, x2) in enumerate(((4e-4, 2e-6), (-3e-4, -1e-6), (2e-4, 3e-6))):
        vehicle[f"TC_A0_X0_{i}"], vehicle[f"TC_A0_X1_{i}"], vehicle[f"TC_A0_X2_{i}"] = 0.002, x1, x2
    for axis, name in enumerate("XYZ"):
        vehicle[f"CAL_ACC0_{name}OFF"] = float(imu.stale_offset[axis])
        vehicle[f"CAL_ACC0_{name}SCALE"] = float(imu.stale_scale[axis])
        vehicle[f"CAL_GYRO0_{name}OFF"] = float(imu.gyro_offset[axis])
    thermal = px4_thermal_offset(vehicle, 0, board.temperature)
    assert np.ptp(thermal, axis=0).max() / MG > 1
    accel = ((imu.raw - thermal - imu.stale_offset) * imu.stale_scale) @ YAW_90.T
    gyro = (imu.gyro_raw - imu.gyro_offset) @ YAW_90.T
    log = tmp_path / "warm.ulg"
    write_ulog(log, [("sensor_accel", 0, sensor_triplet_array(board.t_us, imu.raw, DEVICES[0], board.temperature)),
                     ("sensor_combined", 0, sensor_combined_array(board.t_us, accel, gyro)),
                     ("sensor_selection", 0, sensor_selection_array(board.t_us[::100], DEVICES[0], DEVICES[0]))],
               parameters=vehicle)
    calibration = tmp_path / "px4.yaml"
    assert main(["replay", str(log), "-o", str(calibration)]) == 0
    assert "TC_A" in capsys.readouterr().out
    exported_path = tmp_path / "px4.params"
    assert main(["export", str(calibration), "--to", "px4", "-o", str(exported_path)]) == 0
    said = capsys.readouterr().out
    stated = float(re.search(r"worst ([0-9.]+) mg", said).group(1))
    exported = parse_parameter_text(exported_path.read_text(), str(exported_path)).values
    assert exported["TC_A_ENABLE"] == 0 and exported["TC_G_ENABLE"] == 0
    assert re.search(r"TC_A_ENABLE 0.*every accelerometer", said), said
    loaded = {**vehicle, **exported}
    error = worst_error_mg(px4_vehicle(loaded, 0, imu.raw, board.temperature), imu)
    assert error < stated + 0.5, f"{error:.2f} mg, stated {stated:.2f} mg"
