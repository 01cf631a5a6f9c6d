"""accel-calib check through the CLI: the same sensor holds (exit 0) on every format replay reads, a 5 mg
bias step is flagged (exit 3, the axis named), one attitude cannot tell (exit 1, the orientations that
would), bad input is one line. The statistics over many seeds: test/core/test_check.py."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from accel_calibration.cli.main import main
from accel_calibration.core.calibration import Calibration
from accel_calibration.core.units import MG
from accel_calibration.io.calibration_file import save_calibration
from msg_tools.bag_writer import write_session_bag
from msg_tools.dataflash_writer import FORMATS_4X, imu_records, write_dataflash
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, rotation_with_up, spread_orientations
from msg_tools.ulog_writer import sensor_combined_array, write_ulog

from helpers.one_line import refused

START_NS = 1_700_000_000_000_000_000


def truth() -> SensorErrors:
    return SensorErrors.mpu6050_like(np.random.default_rng(5), noise_mps2=0.02)


def samples(errors: SensorErrors, seed: int, level_only: bool = False):
    rng = np.random.default_rng(seed)
    # The first dwell is the detector's warm-up: it learns the noise floor there.
    rotations = ([rotation_with_up([0.0, 0.0, 1.0])] * 4 if level_only
                 else [rotation_with_up([0.0, 0.0, 1.0]), *spread_orientations(10, rng)])
    return SyntheticImu(errors, rotations, dwell_s=2.5, move_s=0.8, rate_hz=100.0, seed=seed).samples()


def write_recording(path, s, storage: str) -> None:
    if storage == "csv":
        columns = np.column_stack([s.accel_raw, s.gyro_raw, s.temperature_degc])
        rows = [f"{START_NS + t},{','.join(repr(float(v)) for v in row)}" for t, row in zip(s.t_ns, columns)]
        path.write_text("t_ns,ax,ay,az,gx,gy,gz,temperature\n" + "\n".join(rows) + "\n")
    elif storage == "ulog":
        t_us = (START_NS + s.t_ns) // 1000
        write_ulog(path, [("sensor_combined", 0, sensor_combined_array(t_us, s.accel_raw, s.gyro_raw))])
    elif storage == "dataflash":
        t_us = (START_NS + s.t_ns) // 1000
        write_dataflash(path, FORMATS_4X, imu_records(t_us, s.accel_raw, s.gyro_raw, s.temperature_degc))
    else:
        write_session_bag(path, s, start_ns=START_NS, storage=storage)


@pytest.fixture(scope="module")
def calibration_file(tmp_path_factory):
    """The sensor's calibration as a fit of it leaves it: its truth, within sigmas of a good session."""
    errors = truth()
    path = tmp_path_factory.mktemp("check") / "cal.yaml"
    save_calibration(Calibration(bias=errors.bias_mps2, matrix=errors.matrix, bias_sigma=np.full(3, 0.1 * MG),
                                 matrix_sigma=np.where(np.tril(np.ones((3, 3))) > 0, 1e-4, 0.0)), str(path))
    return path


@pytest.mark.parametrize("storage, name", [("csv", "rec.csv"), ("sqlite3", "bag"), ("mcap", "rec.mcap"),
                                           ("ulog", "rec.ulg"), ("dataflash", "rec.bin")])
def test_the_same_sensor_holds_on_every_format(calibration_file, tmp_path, capsys, storage, name):
    path = tmp_path / name
    write_recording(path, samples(truth(), seed=11), storage)
    code = main(["check", str(calibration_file), str(path)])
    out = capsys.readouterr().out
    assert code == 0, out
    assert out.startswith("holds: 10 poses agree"), out
    assert "bias x:" in out and "scale z:" in out and "not observable" not in out


def test_a_5_mg_bias_step_is_flagged_with_its_axis(calibration_file, tmp_path, capsys):
    errors = truth()
    moved = dataclasses.replace(errors, bias_mps2=errors.bias_mps2 + np.array([0.0, 5 * MG, 0.0]))
    path = tmp_path / "moved.csv"
    write_recording(path, samples(moved, seed=12), "csv")
    assert main(["check", str(calibration_file), str(path)]) == 3
    verdict = capsys.readouterr().out.splitlines()[0]
    assert verdict.startswith("moved: bias y changed by +"), verdict
    change_mg = float(verdict.split("by ")[1].split(" mg")[0])
    assert abs(change_mg - 5.0) < 0.5, verdict
    assert "bias x" not in verdict and "bias z" not in verdict


def test_one_attitude_cannot_tell_and_says_which_orientations_would(calibration_file, tmp_path, capsys):
    path = tmp_path / "level.csv"
    write_recording(path, samples(truth(), seed=13, level_only=True), "csv")
    assert main(["check", str(calibration_file), str(path)]) == 1
    verdict = capsys.readouterr().out.splitlines()[0]
    assert verdict.startswith("cannot tell: 1 still pose found"), verdict  # one stillness: one pose
    assert "bias z" in verdict and "turn z down" in verdict, verdict


def test_bad_input_is_one_line(calibration_file, tmp_path, capsys):
    path = tmp_path / "rec.csv"
    write_recording(path, samples(truth(), seed=11), "csv")
    refused(capsys, ["check", tmp_path / "absent.yaml", path], "absent.yaml")
    refused(capsys, ["check", calibration_file, tmp_path / "absent.csv"], "absent.csv")
    refused(capsys, ["check", calibration_file, path, "--k-sigma", "0"], "--k-sigma must be a positive number")


LSB_MPS2 = 4 * MG  # a +-16 g part read at 12 bits


@pytest.mark.parametrize("seed", range(4))
def test_samples_quantised_above_their_noise_do_not_read_as_moved(tmp_path, capsys, seed):
    """0.5 mg of noise under a 4 mg LSB: a pose's mean is off by up to half an LSB whatever its sample count,
    and its samples' scatter says nothing of that. The sensor is unchanged: never 'moved'."""
    errors = SensorErrors.mpu6050_like(np.random.default_rng(40 + seed), noise_mps2=0.5 * MG)
    s = samples(errors, seed=40 + seed)
    s = dataclasses.replace(s, accel_raw=np.round(s.accel_raw / LSB_MPS2) * LSB_MPS2)
    path, calibration = tmp_path / "quantised.csv", tmp_path / "cal.yaml"
    write_recording(path, s, "csv")
    save_calibration(Calibration(bias=errors.bias_mps2, matrix=errors.matrix, bias_sigma=np.full(3, 0.1 * MG),
                                 matrix_sigma=np.where(np.tril(np.ones((3, 3))) > 0, 1e-4, 0.0)), str(calibration))
    code = main(["check", str(calibration), str(path)])
    out = capsys.readouterr().out
    assert code != 3, out
    assert "quantised" in out, out  # the figures say the LSB they allowed for


def thermal_calibration(path) -> None:
    """The truth with a temperature model calibrated over 20..30 degC (no drift: the sensor has none)."""
    from accel_calibration.core.temperature_models import TemperatureModel

    errors = truth()
    model = TemperatureModel(kind="polynomial", reference_degc=25.0, range_degc=(20.0, 30.0),
                             bias_coefficients=np.zeros((1, 3)), scale_coefficients=np.zeros((1, 3)))
    save_calibration(Calibration(bias=errors.bias_mps2, matrix=errors.matrix, bias_sigma=np.full(3, 0.1 * MG),
                                 matrix_sigma=np.where(np.tril(np.ones((3, 3))) > 0, 1e-4, 0.0), temperature=model),
                     str(path))


@pytest.mark.parametrize("temperature, said", [(45.0, "outside"), (None, "no temperature"),
                                                (float("nan"), "no temperature")])
def test_a_temperature_model_checked_where_it_cannot_be_says_so(tmp_path, capsys, temperature, said):
    calibration, path = tmp_path / "thermal.yaml", tmp_path / "rec.csv"
    thermal_calibration(calibration)
    s = samples(truth(), seed=11)
    if temperature is None:
        columns = np.column_stack([s.accel_raw, s.gyro_raw])
        header = "t_ns,ax,ay,az,gx,gy,gz"
    else:
        columns = np.column_stack([s.accel_raw, s.gyro_raw, np.full(len(s.t_ns), temperature)])
        header = "t_ns,ax,ay,az,gx,gy,gz,temperature"
    rows = [f"{START_NS + t},{','.join(repr(float(v)) for v in row)}" for t, row in zip(s.t_ns, columns)]
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    code = main(["check", str(calibration), str(path)])
    captured = capsys.readouterr()
    assert code == 1, captured.out + captured.err
    verdict = captured.out.splitlines()[0]
    assert verdict.startswith("cannot tell:") and said in verdict and "20.0..30.0 degC" in verdict, verdict


def test_a_temperature_model_within_its_range_holds(tmp_path, capsys):
    calibration, path = tmp_path / "thermal.yaml", tmp_path / "rec.csv"
    thermal_calibration(calibration)
    write_recording(path, samples(truth(), seed=11), "csv")  # the synthetic sensor sits at 25 degC
    assert main(["check", str(calibration), str(path)]) == 0, capsys.readouterr().out
