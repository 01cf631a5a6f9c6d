"""--latitude/--height through fit, replay and check: a fit with the local g recovers the scale within its
sigma where 9.80665 would be off by the ratio; the file records where its g came from and loads it back;
older files load; --gravity with --latitude is one line."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from accel_calibration.cli.main import main
from accel_calibration.core.calibration import Calibration
from accel_calibration.core.gravity import normal_gravity
from accel_calibration.core.units import STANDARD_GRAVITY
from accel_calibration.io.calibration_file import load_calibration, save_calibration
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, rotation_with_up, spread_orientations

from helpers.one_line import refused

EQUATOR_G = normal_gravity(0.0)


@pytest.fixture(scope="module")
def equator(tmp_path_factory):
    """A pose table of a sensor at the equator (g = 9.78033 m/s^2, 0.27 % below 1 g), and its truth."""
    rng = np.random.default_rng(21)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    directions = np.array([r.inv().apply([0.0, 0.0, 1.0]) for r in spread_orientations(24, rng)])
    means = errors.raw_from_true(EQUATOR_G * directions) + rng.normal(0.0, 0.02 / np.sqrt(200), (24, 3))
    path = tmp_path_factory.mktemp("gravity") / "poses.csv"
    path.write_text("ax,ay,az\n" + "".join(f"{a!r},{b!r},{c!r}\n" for a, b, c in means.tolist()))
    return path, errors


def test_a_fit_with_the_local_g_recovers_the_scale_where_1_g_is_off_by_the_ratio(equator, tmp_path):
    poses, errors = equator
    local, standard = tmp_path / "local.yaml", tmp_path / "standard.yaml"
    assert main(["fit", str(poses), "-o", str(local), "--latitude", "0"]) == 0
    assert main(["fit", str(poses), "-o", str(standard)]) == 0
    truth = np.diag(errors.matrix)
    fitted = load_calibration(str(local))
    scale, sigma = np.diag(fitted.matrix), np.diag(fitted.matrix_sigma)
    assert np.all(np.abs(scale - truth) < 4 * sigma), (scale - truth) / sigma
    assert fitted.gravity == EQUATOR_G
    assert fitted.gravity_source == "WGS84 normal gravity, latitude 0.00 deg, height 0 m"
    off = load_calibration(str(standard))
    ratio = STANDARD_GRAVITY / EQUATOR_G  # 1 + 2690 ppm
    assert np.all(np.abs(np.diag(off.matrix) / truth - ratio) < 4 * sigma / truth)
    assert np.all(np.abs(np.diag(off.matrix) - truth) > 20 * sigma)  # ~40 sigma: far beyond what it admits
    assert off.gravity_source == "standard"
    assert yaml.safe_load(local.read_text())["accel_calibration"]["gravity_source"].startswith("WGS84")


def test_a_file_without_gravity_source_still_loads(equator, tmp_path):
    poses, _ = equator
    path = tmp_path / "given.yaml"
    assert main(["fit", str(poses), "-o", str(path), "--gravity", "9.7803"]) == 0
    assert load_calibration(str(path)).gravity_source == "given"
    text = "".join(line for line in path.read_text().splitlines(keepends=True) if "gravity_source" not in line)
    older = tmp_path / "older.yaml"
    older.write_text(text)
    assert load_calibration(str(older)).gravity_source == ""


def test_replay_and_check_take_the_latitude(tmp_path, capsys):
    rng = np.random.default_rng(4)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    g = normal_gravity(60.0, 2000.0)
    rotations = [rotation_with_up([0.0, 0.0, 1.0]), *spread_orientations(14, rng)]
    s = SyntheticImu(errors, rotations, dwell_s=2.0, move_s=0.8, rate_hz=100.0, gravity=g, seed=4).samples()
    recording = tmp_path / "rec.csv"
    rows = "".join(f"{t},{a!r},{b!r},{c!r}\n" for t, (a, b, c) in zip(s.t_ns.tolist(), s.accel_raw.tolist()))
    recording.write_text("t_ns,ax,ay,az\n" + rows)
    calibration = tmp_path / "cal.yaml"
    assert main(["replay", str(recording), "-o", str(calibration), "--latitude", "60", "--height", "2000"]) == 0
    fitted = load_calibration(str(calibration))
    assert fitted.gravity == g and fitted.gravity_source.endswith("latitude 60.00 deg, height 2000 m")
    assert main(["check", str(calibration), str(recording), "--latitude", "60", "--height", "2000"]) == 0
    assert f"g = {g:.7g} m/s^2" in capsys.readouterr().out


@pytest.mark.parametrize("command", ["fit", "replay", "check"])
def test_gravity_and_latitude_together_are_one_line(equator, tmp_path, capsys, command):
    poses, _ = equator
    args = {"fit": ["fit", poses, "-o", tmp_path / "c.yaml"], "replay": ["replay", poses],
            "check": ["check", tmp_path / "c.yaml", poses]}[command]
    refused(capsys, [*args, "--gravity", "9.79", "--latitude", "47"], "--gravity and --latitude exclude each other")
    refused(capsys, [*args, "--height", "500"], "--height needs --latitude")
    refused(capsys, [*args, "--latitude", "91"], "--latitude must be within -90..90")


@pytest.fixture(scope="module")
def equator_recording(tmp_path_factory):
    """A sensor recorded at the equator (g 0.27 % below 1 g) and its true calibration, whose file says 1 g: only
    the local g given somewhere tells the check the sensor has not changed."""
    rng = np.random.default_rng(8)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    rotations = [rotation_with_up([0.0, 0.0, 1.0]), *spread_orientations(12, rng)]
    s = SyntheticImu(errors, rotations, dwell_s=2.0, move_s=0.8, rate_hz=100.0, gravity=EQUATOR_G, seed=8).samples()
    folder = tmp_path_factory.mktemp("equator")
    recording = folder / "rec.csv"
    rows = "".join(f"{t},{a!r},{b!r},{c!r}\n" for t, (a, b, c) in zip(s.t_ns.tolist(), s.accel_raw.tolist()))
    recording.write_text("t_ns,ax,ay,az\n" + rows)
    calibration = folder / "cal.yaml"
    save_calibration(Calibration(bias=errors.bias_mps2, matrix=errors.matrix, bias_sigma=np.full(3, 1e-4),
                                 matrix_sigma=np.where(np.tril(np.ones((3, 3))) > 0, 1e-5, 0.0)), str(calibration))
    return calibration, recording, folder


def params_file(folder, name: str, values: dict) -> str:
    path = folder / name
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": values}}))
    return str(path)


def test_check_takes_the_local_g_from_wherever_it_is_given(equator_recording, capsys):
    calibration, recording, folder = equator_recording
    check = ["check", str(calibration), str(recording)]
    assert main(check) == 3  # 1 g against a sensor at the equator: its scale looks 0.27 % off
    assert "scale" in capsys.readouterr().out.splitlines()[0]
    for given in (["--latitude", "0"], ["-p", "latitude_deg:=0.0"], ["-p", "latitude_deg:=0.0", "-p", "height_m:=0.0"],
                  ["-p", f"gravity:={EQUATOR_G!r}"], ["--gravity", repr(EQUATOR_G)],
                  ["--params-file", params_file(folder, "lat.yaml", {"latitude_deg": 0.0})],
                  ["--params-file", params_file(folder, "g.yaml", {"gravity": EQUATOR_G})]):
        assert main([*check, *given]) == 0, given
        assert f"g = {EQUATOR_G:.7g} m/s^2" in capsys.readouterr().out, given


def test_the_package_params_file_says_no_local_g(equator_recording, capsys):
    """Its gravity 9.80665 and latitude .nan are the defaults: a flag beside it is no conflict."""
    calibration, recording, _ = equator_recording
    shipped = str(Path(__file__).parents[2] / "config" / "accel_calibration.yaml")
    assert main(["check", str(calibration), str(recording), "--params-file", shipped, "--latitude", "0"]) == 0
    capsys.readouterr()


@pytest.mark.parametrize("command", ["replay", "check"])
def test_local_g_given_twice_differently_is_one_line(equator_recording, capsys, command):
    calibration, recording, folder = equator_recording
    args = [command, *([calibration] if command == "check" else []), recording]
    lat47 = params_file(folder, "lat47.yaml", {"latitude_deg": 47.0})
    refused(capsys, [*args, "--latitude", "0", "-p", "latitude_deg:=47.0"], "latitude", "-p", "--latitude")
    refused(capsys, [*args, "--params-file", lat47, "--latitude", "0"], "latitude", "--params-file", "--latitude")
    refused(capsys, [*args, "-p", "gravity:=9.79", "--latitude", "0"], "exclude each other")
    refused(capsys, [*args, "--params-file", lat47, "-p", "gravity:=9.79"], "exclude each other")
    refused(capsys, [*args, "-p", "height_m:=500.0"], "height_m (-p height_m) needs latitude_deg")
