"""Hostile files: a calibration file is put in force (node start-up, `apply`, `report`) only if plausible;
loading is safe (size cap, no alias bombs, no deep nesting, no FIFO/device/directory, absurd numbers);
overflowing CSV values and options are one line with no RuntimeWarning; raw counts still fit."""
from __future__ import annotations

import os
import threading
import tracemalloc

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from accel_calibration import Calibration, CalibrationError, fit, load_calibration
from accel_calibration.cli.main import main
from accel_calibration.core.plausibility import plausibility_refusal
from accel_calibration.core.refusal import Gate
from accel_calibration.core.temperature_models import TemperatureModel
from accel_calibration.io.calibration_file import calibration_from_yaml, calibration_to_dict, save_calibration

from helpers.one_line import refused

G = 9.80665
MG = G * 1e-3


def good_body():
    cal = Calibration(bias=[0.2, -0.3, 0.1], matrix=[[1.01, 0, 0], [0.01, 0.98, 0], [-0.005, 0.008, 1.02]],
                      gyro_bias_radps=[0.01, -0.02, 0.005])
    return calibration_to_dict(cal)["accel_calibration"]


def polynomial_block(bias_c1=(0.001, -0.001, 0.0005), scale_d1=(1e-4, -1e-4, 0.0), range_degc=(-20.0, 60.0)):
    return {"model": "polynomial", "reference_degc": 25.0, "range_degc": list(range_degc),
            "bias_coefficients": [list(bias_c1)], "scale_coefficients": [list(scale_d1)]}


def write_body(path, **changes):
    body = good_body()
    body.update(changes)
    path.write_text(yaml.safe_dump({"accel_calibration": body}, sort_keys=False))
    return path


# ---------------------------------------------------------------------------------------------- plausibility

IMPLAUSIBLE = {
    "mirrored": (dict(model="reference12", matrix=[[-1.01, 0, 0], [0, 0.98, 0], [0, 0, 1.02]]), "mirrored"),
    "rows swapped": (dict(model="reference12", matrix=[[0, 0.98, 0], [1.01, 0, 0], [0, 0, 1.02]]), "mirrored"),
    "six not diagonal": (dict(model="six", matrix=[[1.01, 0.02, 0], [0, 0.98, 0], [0, 0, 1.02]]), "diagonal"),
    "sphere9 upper": (dict(matrix=[[1.01, 0, 0.03], [0.01, 0.98, 0], [0, 0, 1.02]]), "lower-triangular"),
    "reference15 without quadratic": (dict(model="reference15", matrix=[[1.01, 0, 0], [0, 0.98, 0], [0, 0, 1.02]]),
                                      "needs its quadratic"),
    "quadratic on sphere9": (dict(quadratic=[1e-4, 0, 0]), "has no quadratic term"),
    "gyro bias": (dict(gyro_bias_radps=[2.5, 0.0, 0.0]), "gyro bias 2.5 rad/s"),
    "bias at reference": (dict(bias=[2.5, 0, 0]), "gate bias"),
    # Within the gates at T_ref = 25 degC, outside them at the edge of the calibrated range:
    "temperature bias drift": (dict(temperature=polynomial_block(bias_c1=(0.05, 0, 0))),
                               "temperature block: gate bias: |b| 2.0"),
    "temperature gain drift": (dict(temperature=polynomial_block(scale_d1=(0.004, 0, 0))),
                               "temperature block: gate scale: correction gain x 1.2"),
    "temperature gain flips": (dict(temperature=polynomial_block(scale_d1=(0.03, 0, 0))), "temperature block"),
    "temperature range": (dict(temperature=polynomial_block(range_degc=(-1e6, 1e6))), "not a sensor's"),
    "format version 0": (dict(format_version=0), "format_version must be 1 or more"),
}


@pytest.mark.parametrize("name", sorted(IMPLAUSIBLE))
def test_implausible_files_are_never_put_in_force_by_apply_or_report(tmp_path, capsys, name):
    change, message = IMPLAUSIBLE[name]
    cal = write_body(tmp_path / "cal.yaml", **change)
    before = cal.read_bytes()
    (tmp_path / "in.csv").write_text("ax,ay,az,temperature\n0.2,-0.3,9.9,25\n")
    (tmp_path / "poses.csv").write_text("ax,ay,az\n" + "0,0,9.8\n0,9.8,0\n9.8,0,0\n")
    refused(capsys, ["apply", "-c", cal, tmp_path / "in.csv", tmp_path / "out.csv"], message)
    refused(capsys, ["report", cal, "--poses", tmp_path / "poses.csv", "-o", tmp_path / "r.png"], message)
    assert not (tmp_path / "out.csv").exists() and not (tmp_path / "r.png").exists()
    assert cal.read_bytes() == before


def test_the_temperature_gates_hold_over_the_whole_range_not_only_at_the_reference():
    """The old check looked at b and M alone (T_ref): a drift of 50 mg/degC passed it."""
    body = good_body()
    base = calibration_from_yaml(yaml.safe_dump({"accel_calibration": body}))
    assert plausibility_refusal(base) is None
    body["temperature"] = polynomial_block(bias_c1=(0.05, 0, 0))
    drifting = calibration_from_yaml(yaml.safe_dump({"accel_calibration": body}))
    refusal = plausibility_refusal(drifting)
    assert refusal is not None and refusal.gate is Gate.BIAS, refusal
    assert "|b| 2.05 m/s^2 at -20.0 degC" in refusal.text  # 0.2 - 0.05 x 45
    np.testing.assert_allclose(drifting.apply([0.2, -0.3, 9.9], 25.0), base.apply([0.2, -0.3, 9.9]), atol=1e-12)
    # The same drift over a narrow range stays within the gate: it is the range that makes it implausible.
    body["temperature"] = polynomial_block(bias_c1=(0.05, 0, 0), range_degc=(20.0, 30.0))
    assert plausibility_refusal(calibration_from_yaml(yaml.safe_dump({"accel_calibration": body}))) is None


gains = st.floats(min_value=0.92, max_value=1.08)
small = st.floats(min_value=-0.02, max_value=0.02)
biases = st.floats(min_value=-1.9, max_value=1.9)


@settings(max_examples=60, deadline=None)
@given(diagonal=st.tuples(gains, gains, gains), lower=st.tuples(small, small, small),
       bias=st.tuples(biases, biases, biases), row=st.integers(0, 2),
       drift=st.tuples(st.floats(-2e-3, 2e-3), st.floats(-2e-3, 2e-3), st.floats(-2e-3, 2e-3)))
def test_plausible_calibrations_pass_and_their_mirror_images_never_do(diagonal, lower, bias, row, drift):
    matrix = np.diag(diagonal)
    matrix[1, 0], matrix[2, 0], matrix[2, 1] = lower
    bias = np.array(bias) * 0.9  # keep the drift over the range (<= 0.1 m/s^2) inside the bias gate
    temperature = TemperatureModel("polynomial", 25.0, (20.0, 30.0), bias_coefficients=[list(drift)])
    for model in (None, temperature):
        cal = Calibration(bias=bias, matrix=matrix, temperature=model)
        assert plausibility_refusal(cal) is None
        mirrored = matrix.copy()
        mirrored[row] *= -1
        refusal = plausibility_refusal(Calibration(bias=bias, matrix=mirrored, model="reference12",
                                                    temperature=model))
        assert refusal is not None and "mirrored" in refusal.text


def test_a_fitted_calibration_with_a_temperature_model_is_plausible(tmp_path):
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(60, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    temperatures = np.repeat([0.0, 20.0, 40.0], 20)
    raw = G * directions * [1.01, 0.98, 1.02] + [0.2, -0.3, 0.1] + np.outer(temperatures - 20, [1e-3, -1e-3, 5e-4])
    raw += rng.normal(0, 0.2 * MG, raw.shape)
    result = fit(raw, temperature_degc=temperatures, temperature_model="polynomial")
    assert result.success, result.message
    save_calibration(result.calibration, tmp_path / "cal.yaml")
    assert plausibility_refusal(load_calibration(tmp_path / "cal.yaml")) is None


# ------------------------------------------------------------------------------------------------ safe loading

def _unblock_fifo_readers(path):
    """A writer that opens the FIFO once: a reader that (wrongly) opened it returns instead of hanging
    the test, and the test then fails on its message. Released at the end by a non-blocking reader."""
    opener = threading.Thread(target=lambda: os.close(os.open(path, os.O_WRONLY)), daemon=True)
    opener.start()
    return opener


def _release(opener, path):
    if opener.is_alive():
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # lets the blocked writer's open return
        opener.join()
        os.close(fd)


def test_a_fifo_device_or_directory_is_refused_before_it_is_opened(tmp_path, capsys):
    fifo = tmp_path / "cal.yaml"
    os.mkfifo(fifo)
    opener = _unblock_fifo_readers(fifo)
    try:
        (tmp_path / "in.csv").write_text("ax,ay,az\n0,0,9.8\n")
        save_calibration(Calibration.identity(), tmp_path / "x.yaml")
        refused(capsys, ["apply", "-c", fifo, tmp_path / "in.csv", tmp_path / "out.csv"], "is a FIFO")
        refused(capsys, ["fit", fifo, "-o", tmp_path / "y.yaml"], "is a FIFO")
        refused(capsys, ["apply", "-c", tmp_path / "x.yaml", fifo, tmp_path / "out.csv"], "is a FIFO")
        refused(capsys, ["replay", tmp_path, "--params-file", fifo], "is a FIFO")
        assert opener.is_alive()  # nobody opened it
    finally:
        _release(opener, fifo)
    with pytest.raises(CalibrationError, match="is a device"):
        load_calibration("/dev/zero")  # would read forever
    with pytest.raises(CalibrationError, match="is a directory"):
        load_calibration(tmp_path)


def test_size_cap(tmp_path):
    big = write_body(tmp_path / "cal.yaml")
    with big.open("a") as stream:
        stream.write("# padding\n" * 120_000)
    with pytest.raises(CalibrationError, match="too large for a calibration file"):
        load_calibration(big)


def billion_laughs(levels=9):
    lines = ['a0: &a0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for k in range(1, levels):
        lines.append(f"a{k}: &a{k} [" + ",".join([f"*a{k - 1}"] * 9) + "]")
    return "accel_calibration:\n  model: sphere9\n  bias: [0, 0, 0]\n  matrix: [[1,0,0],[0,1,0],[0,0,1]]\n" + \
        "\n".join("  " + line for line in lines) + "\n"


@pytest.mark.parametrize("text, message", [
    (billion_laughs(), "aliases"),
    ("accel_calibration: " + "[" * 200_000 + "]" * 200_000 + "\n", "nested deeper"),
    ("accel_calibration:\n" + "".join("  " * k + f"k{k}:\n" for k in range(1, 400)), "nested deeper"),
])
def test_yaml_bombs_are_refused_quickly_without_memory_growth(tmp_path, text, message):
    path = tmp_path / "cal.yaml"
    path.write_text(text)
    tracemalloc.start()
    try:
        with pytest.raises(CalibrationError, match=message) as refused:
            load_calibration(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert "\n" not in str(refused.value)
    assert peak < 4 * len(text) + 2_000_000, peak  # the text and the parser's buffers, no expansion


@pytest.mark.parametrize("change, message", [
    (dict(bias=[1.0e200, 0.0, 0.0]), "beyond any calibration's range"),
    (dict(matrix=[[1.0e200, 0, 0], [0, 1, 0], [0, 0, 1]]), "beyond any calibration's range"),
    (dict(quality={"poses": 10**23, "residual_rms_mg": 1.0, "residual_max_mg": 2.0}), "beyond"),
    (dict(quality={"poses": 1.0e23, "residual_rms_mg": 1.0, "residual_max_mg": 2.0}), "quality.poses holds 1e+23"),
    (dict(quality={"poses": 2.5, "residual_rms_mg": 1.0, "residual_max_mg": 2.0}), "quality.poses must be"),
    (dict(bias=[10**2000, 0, 0]), "an integer of about 2000 digits"),
    (dict(bias=["1e200", 0, 0]), "bias must be numbers"),
    (dict(gyro_bias_radps=[True, 0, 0]), "gyro_bias_radps must be numbers"),
    (dict(temperature=dict(polynomial_block(), bias_coefficients=[[1.0e300, 0, 0]])), "beyond"),
])
def test_absurd_numbers_are_one_line(tmp_path, capsys, change, message):
    cal = write_body(tmp_path / "cal.yaml", **change)
    (tmp_path / "in.csv").write_text("ax,ay,az\n0,0,9.8\n")
    refused(capsys, ["apply", "-c", cal, tmp_path / "in.csv", tmp_path / "out.csv"], message)


def test_a_date_that_is_not_a_date_is_one_line():
    with pytest.raises(CalibrationError, match="not valid YAML"):
        calibration_from_yaml("accel_calibration: {created: 2024-13-45}\n", "x.yaml")


# --------------------------------------------------------------------------------------- CSV and overflow

def sphere_poses(n=30, seed=2):
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    directions[:6] = np.vstack([np.eye(3), -np.eye(3)])
    matrix = np.array([[1.01, 0, 0], [0.01, 0.98, 0], [-0.005, 0.008, 1.02]])
    return (G * directions) @ np.linalg.inv(matrix).T + [0.2, -0.3, 0.1] + rng.normal(0, 0.2 * MG, (n, 3)), matrix


def write_csv(path, rows, header="ax,ay,az"):
    path.write_text(header + "\n" + "".join(",".join(repr(float(v)) for v in row) + "\n" for row in rows))
    return path


@pytest.mark.filterwarnings("error")  # RuntimeWarning (overflow, invalid) fails the test
@pytest.mark.parametrize("scale", [1e300, 1e-300, 1e13])
def test_data_scaled_far_out_of_range_is_one_line_without_warnings(tmp_path, capsys, scale):
    raw, _ = sphere_poses()
    poses = write_csv(tmp_path / "p.csv", raw * scale)
    refused(capsys, ["fit", poses, "-o", tmp_path / "cal.yaml"],
                   "median |a| is 9.696e-300 m/s^2" if scale < 1 else "a corrupt value or the wrong units")
    assert not (tmp_path / "cal.yaml").exists()


@pytest.mark.filterwarnings("error")
def test_1e308_in_csv_is_one_line_without_warnings(tmp_path, capsys):
    raw, _ = sphere_poses()
    raw[5, 1] = 1e308
    poses = write_csv(tmp_path / "p.csv", raw)
    refused(capsys, ["fit", poses, "-o", tmp_path / "cal.yaml"], "row 7, column ay: 1e+308 is outside")
    save_calibration(Calibration.identity(), tmp_path / "cal.yaml")
    refused(capsys, ["apply", "-c", tmp_path / "cal.yaml", poses, tmp_path / "out.csv"], "row 7, column ay")
    temps = write_csv(tmp_path / "t.csv", np.column_stack([raw[:5], [1e308, 0, 0, 0, 0]]),
                      header="ax,ay,az,temperature")
    refused(capsys, ["apply", "-c", tmp_path / "cal.yaml", temps, tmp_path / "out.csv"],
                   "column temperature: 1e+308 is outside")


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("option, value, message", [
    ("--reference-temperature", "1e300", "--reference-temperature must be a sensor temperature"),
    ("--gravity", "inf", "--gravity must be a finite number"),
    ("--segment-width", "nan", "--segment-width must be a finite number"),
    ("--min-span", "1e999", "--min-span must be a finite number"),
])
def test_overflowing_options_are_one_line(tmp_path, capsys, option, value, message):
    raw, _ = sphere_poses()
    poses = write_csv(tmp_path / "p.csv", np.column_stack([raw, np.linspace(0, 40, len(raw))]),
                      header="ax,ay,az,temperature")
    refused(capsys, ["fit", poses, "--temperature-model", "polynomial", option, value,
                            "-o", tmp_path / "cal.yaml"], message)


def test_a_duplicated_column_is_refused_naming_it(tmp_path, capsys):
    (tmp_path / "p.csv").write_text("ax,ay,az,AY\n1,2,3,4\n")
    refused(capsys, ["fit", tmp_path / "p.csv", "-o", tmp_path / "cal.yaml"], "column ay appears more than once")
    (tmp_path / "q.csv").write_text("t,ax,ay,az,t\n1,2,3,4,5\n")
    save_calibration(Calibration.identity(), tmp_path / "cal.yaml")
    refused(capsys, ["apply", "-c", tmp_path / "cal.yaml", tmp_path / "q.csv", tmp_path / "out.csv"],
                   "column t appears more than once")


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("model", ["six", "sphere9", "reference12"])
def test_high_resolution_raw_counts_fit(tmp_path, model):
    """256 000 LSB/g (a 24-bit part): M maps counts to m/s^2, ~4e-5 per entry, det ~6e-14. Nothing may
    refuse it for an absolute determinant."""
    lsb_per_g = 256_000.0
    raw_mps2, matrix = sphere_poses(n=40, seed=5)
    counts_bias = np.array([300.0, -200.0, 100.0])
    counts = raw_mps2 / G * lsb_per_g + counts_bias
    directions = (raw_mps2 - [0.2, -0.3, 0.1]) @ matrix.T / G
    result = fit(counts, model=model, reference=directions if model == "reference12" else None)
    assert result.success, result.message
    cal = result.calibration
    to_counts = lsb_per_g / G
    expected = matrix / to_counts
    if model == "six":  # the diagonal model absorbs the misalignment: only the scale is comparable
        np.testing.assert_allclose(np.diag(cal.matrix) * to_counts, np.diag(matrix), rtol=2e-2)
    else:
        np.testing.assert_allclose(cal.matrix * to_counts, matrix, atol=2e-4)
        true_bias = counts_bias + np.array([0.2, -0.3, 0.1]) / G * lsb_per_g  # counts (0.2 mg noise = 51 counts)
        assert np.all(np.abs(cal.bias - true_bias) <= 4 * cal.bias_sigma), (cal.bias - true_bias, cal.bias_sigma)
        assert np.all(cal.bias_sigma / lsb_per_g * 1e3 < 0.1)  # known to 0.1 mg
        assert np.abs(np.linalg.det(expected)) < 1e-12  # the old absolute limit would have refused it
    save_calibration(cal, tmp_path / "counts.yaml")
    assert load_calibration(tmp_path / "counts.yaml") == cal
    write_csv(tmp_path / "counts.csv", counts)
    assert main(["fit", str(tmp_path / "counts.csv"), "--model", "sphere9", "-o", str(tmp_path / "cli.yaml")]) == 0


# ------------------------------------------------------------------------------------------ the node

@pytest.mark.ros
@pytest.mark.parametrize("kind", ["fifo", "temperature drift", "mirrored"])
def test_the_node_refuses_a_fifo_or_implausible_file_at_start_up_and_passes_raw_through(tmp_path, tester, kind):
    from msg_tools.conversions import make_imu
    from msg_tools.node_process import NodeProcess

    cal_file = tmp_path / "cal.yaml"
    opener = None
    if kind == "fifo":
        os.mkfifo(cal_file)
        opener = _unblock_fifo_readers(cal_file)
        expected = "FIFO"
    elif kind == "temperature drift":
        write_body(cal_file, temperature=polynomial_block(bias_c1=(0.05, 0, 0)))
        expected = "temperature block: gate bias"
    else:
        write_body(cal_file, model="reference12", matrix=[[1.01, 0, 0], [0, -0.98, 0], [0, 0, 1.02]])
        expected = "mirrored"
    before = None if kind == "fifo" else cal_file.read_bytes()
    node = NodeProcess(cal_file, log_path=tmp_path / "node.log")
    try:
        tester.wait_ready()
        assert tester.spin_until(lambda: tester.diagnostics and tester.diagnostics[-1]["level"] == b"\x02", 5)
        message = tester.diagnostics[-1]["message"]
        assert "unusable" in message and expected in message, message
        tester.corrected.clear()
        tester.imu_pub.publish(make_imu(1_700_000_000 * 10**9, (0.5, 0.25, 9.5), (0.0, 0.0, 0.0)))
        assert tester.settle(1)
        assert tester.corrected[0].linear_acceleration.x == 0.5  # raw passes through
        assert node.process.poll() is None
        if opener is not None:
            assert opener.is_alive()  # the node never opened the FIFO
    finally:
        assert node.stop() == 0, node.log()
        if opener is not None:
            _release(opener, cal_file)
    assert "Traceback" not in node.log()
    if before is not None:
        assert cal_file.read_bytes() == before
