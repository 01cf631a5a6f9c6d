"""accel-calib export / compare: each exported file, applied with the target's own formula (written here
from the target's source, independently of the package), corrects the sensor our calibration describes
within the cost the export reports; export -> compare gives back that cost (0 for what the target holds
whole); out-of-range values are refused with the range; real autopilot logs are read."""
from __future__ import annotations

import re

import numpy as np
import pytest
from conftest import shared_path
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from accel_calibration.cli.export import fit_for
from accel_calibration.cli.main import main
from accel_calibration.core.axis_calibration import (
    AxisWiseCalibration,
    cost_against,
    lower_triangular_with_rotation,
    raw_for_true,
    sphere_directions,
)
from accel_calibration.core.calibration import Calibration
from accel_calibration.core.temperature_models import TemperatureModel
from accel_calibration.core.units import MG, STANDARD_GRAVITY
from accel_calibration.io.autopilot_params import (
    ParameterFileError,
    ardupilot_parameters,
    parse_parameter_text,
    px4_parameters,
)
from accel_calibration.io.calibration_file import save_calibration
from accel_calibration.io.estimator_yaml import NoiseFigures, kalibr_imu_yaml

FLOAT32_SLACK_MG = 0.01  # the autopilots keep float32 parameters: ~1e-7 relative


def px4_correct(params: dict[str, float], instance: int, raw: np.ndarray, temperature: np.ndarray) -> np.ndarray:
    """PX4: calibration::Accelerometer::Correct, (raw - thermal_offset - offset) .* scale, with
    TemperatureCompensation::calc_thermal_offsets_3D (dT clipped to TMIN..TMAX about TREF, cubic from X0)."""
    p = f"CAL_ACC{instance}_"
    offset = np.array([params[p + "XOFF"], params[p + "YOFF"], params[p + "ZOFF"]])
    scale = np.array([params[p + "XSCALE"], params[p + "YSCALE"], params[p + "ZSCALE"]])
    thermal = np.zeros_like(raw)
    if params.get("TC_A_ENABLE") == 1:
        tc = f"TC_A{instance}_"
        measured = temperature
        delta = np.where(measured > params[tc + "TMAX"], params[tc + "TMAX"] - params[tc + "TREF"],
                         np.where(measured < params[tc + "TMIN"], params[tc + "TMIN"] - params[tc + "TREF"],
                                  measured - params[tc + "TREF"]))
        for i in range(3):
            thermal[:, i] = (params[f"{tc}X0_{i}"] + params[f"{tc}X1_{i}"] * delta + params[f"{tc}X2_{i}"] * delta**2
                             + params[f"{tc}X3_{i}"] * delta**3)
    return (raw - thermal - offset) * scale


def ardupilot_correct(params: dict[str, float], instance: int, raw: np.ndarray,
                      temperature: np.ndarray) -> np.ndarray:
    """ArduPilot: TCal::correct_sensor (v -= P(T - 35) - P(CALTEMP - 35), both clamped to TMIN..TMAX,
    P = (c1 + (c2 + c3 d) d) d * 1e-6), then accel -= offsets, accel *= scale."""
    name = "" if instance == 0 else str(instance + 1)
    offset = np.array([params[f"INS_ACC{name}OFFS_{a}"] for a in "XYZ"])
    scale = np.array([params[f"INS_ACC{name}SCAL_{a}"] for a in "XYZ"])
    v = raw.copy()
    n = instance + 1
    tcal = f"INS_TCAL{n}_"
    if params.get(tcal + "ENABLE") == 1:
        c = [np.array([params[f"{tcal}ACC{k}_{a}"] for a in "XYZ"]) for k in (1, 2, 3)]

        def polynomial(tdiff: np.ndarray) -> np.ndarray:
            d = tdiff[:, None]
            return (c[0] + (c[1] + c[2] * d) * d) * d * 1e-6

        t = np.clip(temperature, params[tcal + "TMIN"], params[tcal + "TMAX"])
        cal_temp = np.clip(np.full_like(t, params[f"INS_ACC{n}_CALTEMP"]), params[tcal + "TMIN"], params[tcal + "TMAX"])
        v = v - polynomial(t - 35.0) + polynomial(cal_temp - 35.0)
    return (v - offset) * scale


def calibration_strategy(with_temperature: bool):
    small = st.floats(-2e-3, 2e-3)
    return st.builds(
        lambda diag, lower, bias, c1, c2, d1, tref: Calibration(
            bias=bias, matrix=np.array([[diag[0], 0, 0], [lower[0], diag[1], 0], [lower[1], lower[2], diag[2]]]),
            temperature=TemperatureModel(kind="polynomial", reference_degc=tref, range_degc=(tref - 20, tref + 20),
                                         bias_coefficients=[c1, c2], scale_coefficients=[d1])
            if with_temperature else None),
        st.lists(st.floats(0.95, 1.05), min_size=3, max_size=3),
        st.lists(small, min_size=3, max_size=3),
        st.lists(st.floats(-0.5, 0.5), min_size=3, max_size=3),
        st.lists(st.floats(-3e-3, 3e-3), min_size=3, max_size=3),
        st.lists(st.floats(-3e-5, 3e-5), min_size=3, max_size=3),
        st.lists(st.floats(-1e-4, 1e-4), min_size=3, max_size=3),
        st.floats(15.0, 40.0))


def _check_target(calibration: Calibration, target: str, tmp_path, seed: int) -> float:
    path = tmp_path / "cal.yaml"
    save_calibration(calibration, path)
    out = tmp_path / f"out.{target}"
    assert main(["export", str(path), "--to", target, "-o", str(out), "--force"]) == 0
    params = parse_parameter_text(out.read_text(), str(out)).values
    cost = cost_against(calibration, fit_for(target, calibration))
    # The calibration's own six faces plus random orientations, over and beyond the calibrated range.
    rng = np.random.default_rng(seed)
    directions = np.vstack([np.eye(3), -np.eye(3), rng.normal(size=(300, 3))])
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    if calibration.temperature is not None:
        low, high = calibration.temperature.range_degc
        temperature = rng.uniform(low, high, len(directions))
    else:
        temperature = np.full(len(directions), 25.0)
    true = directions * STANDARD_GRAVITY
    raw = raw_for_true(calibration, true, temperature)
    correct = px4_correct if target == "px4" else ardupilot_correct
    error_mg = np.linalg.norm(correct(params, 0, raw, temperature) - true, axis=1) / MG
    assert error_mg.max() <= cost.worst_mg + FLOAT32_SLACK_MG
    # What the autopilot applies, read back with the package's own reader, is the same correction.
    assert main(["compare", str(path), str(out)]) == 0
    return cost.worst_mg


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(calibration=calibration_strategy(with_temperature=True), seed=st.integers(0, 2**16))
def test_export_applied_with_the_targets_formula_is_within_the_reported_cost(target, calibration, seed, tmp_path):
    _check_target(calibration, target, tmp_path, seed)


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
def test_a_calibration_the_target_holds_whole_costs_nothing_and_compares_to_zero(target, tmp_path, capsys):
    calibration = Calibration(bias=[0.05, -0.3, 0.2], matrix=np.diag([1.01, 0.99, 1.003]))
    assert _check_target(calibration, target, tmp_path, 1) < 1e-6
    out = capsys.readouterr().out
    assert "difference from" in out and "worst 0.000 mg" in out.splitlines()[-1]


def test_compare_of_an_export_gives_the_exports_cost(tmp_path, capsys):
    calibration = Calibration(bias=[0.05, -0.08, 0.12],
                              matrix=[[1.002, 0, 0], [0.0015, 0.998, 0], [-0.001, 0.0012, 1.004]])
    save_calibration(calibration, tmp_path / "cal.yaml")
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", "px4", "-o", str(tmp_path / "x.params")]) == 0
    reported = capsys.readouterr().out.splitlines()[0]
    assert main(["compare", str(tmp_path / "cal.yaml"), str(tmp_path / "x.params")]) == 0
    compared, compared_rotated = capsys.readouterr().out.splitlines()[-2:]
    worst = reported.split("worst ")[1].split(" mg")[0]
    assert 1.9 < float(worst) < 2.0  # 1.960 mg: up to 1.5 mrad of misalignment at 1 g
    assert f"worst {worst} mg" in compared
    rotated = reported.split("after the best rotation")[1].split("worst ")[1].split(" mg")[0]
    assert 1.2 < float(rotated) < 1.3  # 1.237 mg once the level calibration takes its 1.08 mrad
    assert f"worst {rotated} mg" in compared_rotated


def test_export_refuses_above_max_loss_unless_forced(tmp_path, capsys):
    calibration = Calibration(bias=[0, 0, 0], matrix=[[1.0, 0, 0], [0.01, 1.0, 0], [0, 0, 1.0]])  # 10 mrad
    save_calibration(calibration, tmp_path / "cal.yaml")
    args = ["export", str(tmp_path / "cal.yaml"), "--to", "ardupilot", "-o", str(tmp_path / "x.param")]
    assert main(args) == 1
    error = capsys.readouterr().err
    assert "cannot hold this calibration within 2 mg" in error and "--force" in error
    assert not (tmp_path / "x.param").exists()
    assert main(args + ["--force"]) == 0
    assert main(args + ["--max-loss-mg", "20"]) == 0


@pytest.mark.parametrize("target, scale, offset, expected", [
    ("ardupilot", [1.25, 1, 1], [0, 0, 0], "INS_ACCSCAL_X = 1.25 is outside the range the autopilot accepts, 0.8..1.2"),
    ("ardupilot", [1, 1, 1], [0, 4.0, 0], "INS_ACCOFFS_Y = 4 is outside the range the autopilot accepts, -3.5..3.5"),
    ("px4", [1, 1, 3.5], [0, 0, 0], "CAL_ACC0_ZSCALE = 3.5 is outside the range the autopilot accepts, 0.1..3"),
])
def test_values_outside_the_targets_range_are_refused_naming_it(target, scale, offset, expected):
    """The writers refuse what the target refuses (export refuses sooner: our loader's gates are tighter)."""
    held = AxisWiseCalibration(offset_mps2=offset, scale=scale)
    with pytest.raises(ParameterFileError, match=re.escape(expected)):
        if target == "px4":
            px4_parameters(held, 0)
        else:
            ardupilot_parameters(held, 0, reference_degc=None)


def test_ardupilot_instances_and_px4_ids(tmp_path):
    calibration = Calibration(bias=[0.1, 0.2, 0.3], matrix=np.eye(3), gyro_bias_radps=[0.01, 0.02, 0.03],
                              accel_device_id=1310996)
    save_calibration(calibration, tmp_path / "cal.yaml")
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", "ardupilot", "--instance", "1",
                 "-o", str(tmp_path / "a.param")]) == 0
    values = parse_parameter_text((tmp_path / "a.param").read_text(), "a").values
    assert values["INS_ACC2OFFS_Z"] == pytest.approx(0.3) and values["INS_GYR2OFFS_Y"] == pytest.approx(0.02)
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", "px4", "--instance", "1",
                 "-o", str(tmp_path / "p.params")]) == 0
    values = parse_parameter_text((tmp_path / "p.params").read_text(), "p").values
    assert values["CAL_ACC1_ID"] == 1310996 and values["CAL_GYRO1_ZOFF"] == pytest.approx(0.03)


def _noise_file(tmp_path):
    path = tmp_path / "imu.yaml"
    path.write_text(kalibr_imu_yaml(NoiseFigures(2e-3, 3e-4, 1.7e-4, 2e-5, 200.0), "/imu0"))
    return path


def test_openvins_intrinsics_applied_with_openvins_formula_match_ours(tmp_path):
    """ov_msckf: a_I = R_ACCtoI D_a (a_m - b_a), D_a = Ta^-1, R_ACCtoI = R_IMUtoACC^T; b_a its own state."""
    import yaml

    matrix = np.array([[1.01, 0.004, -0.002], [0.003, 0.99, 0.001], [-0.005, 0.002, 1.002]])  # reference12: full
    calibration = Calibration(bias=[0.1, -0.2, 0.05], matrix=matrix, model="reference12")
    save_calibration(calibration, tmp_path / "cal.yaml")
    out = tmp_path / "kalibr_imu_chain.yaml"
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", "openvins", "--noise", str(_noise_file(tmp_path)),
                 "-o", str(out)]) == 0
    text = out.read_text()
    assert text.startswith("%YAML:1.0")
    imu = yaml.safe_load(text.split("\n", 1)[1])["imu0"]
    assert imu["model"] == "kalibr" and imu["accelerometer_noise_density"] == pytest.approx(2e-3)
    ta, r_imu_to_acc = np.array(imu["Ta"]), np.array(imu["R_IMUtoACC"])
    assert np.allclose(np.triu(np.linalg.inv(ta), 1), 0, atol=1e-12)  # kalibr model: D_a lower-triangular
    raw = np.random.default_rng(3).normal(size=(50, 3)) * 9.8
    openvins = (raw - calibration.bias) @ (r_imu_to_acc.T @ np.linalg.inv(ta)).T
    np.testing.assert_allclose(openvins, calibration.apply(raw), atol=1e-9)


def test_kalibr_needs_noise_and_writes_the_four_fields(tmp_path, capsys):
    save_calibration(Calibration.identity(), tmp_path / "cal.yaml")
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", "kalibr", "-o", str(tmp_path / "imu.yaml")]) == 1
    assert "accel-calib noise" in capsys.readouterr().err
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", "kalibr", "--noise", str(_noise_file(tmp_path)),
                 "--rostopic", "/camera/imu", "-o", str(tmp_path / "kalibr.yaml")]) == 0
    import yaml

    document = yaml.safe_load((tmp_path / "kalibr.yaml").read_text())
    assert document["gyroscope_random_walk"] == pytest.approx(2e-5) and document["rostopic"] == "/camera/imu"
    assert document["update_rate"] == 200


def test_lower_triangular_with_rotation_is_exact():
    rng = np.random.default_rng(5)
    for _ in range(20):
        matrix = np.eye(3) + 0.05 * rng.normal(size=(3, 3))
        rotation, lower = lower_triangular_with_rotation(matrix)
        np.testing.assert_allclose(rotation @ lower, matrix, atol=1e-12)
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        assert np.all(np.diag(lower) > 0) and np.allclose(np.triu(lower, 1), 0)


def test_sphere_directions_cover_the_sphere():
    directions = sphere_directions(2000)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0)
    probe = np.random.default_rng(0).normal(size=(500, 3))
    probe /= np.linalg.norm(probe, axis=1, keepdims=True)
    assert np.max(np.min(np.arccos(np.clip(probe @ directions.T, -1, 1)), axis=1)) < np.radians(4)


def test_compare_reads_the_real_ardupilot_log(tmp_path, capsys):
    save_calibration(Calibration.identity(), tmp_path / "cal.yaml")
    log = shared_path("real/ardupilot/test.BIN")
    assert main(["compare", str(tmp_path / "cal.yaml"), str(log)]) == 0
    out = capsys.readouterr().out
    assert "ardupilot parameters (809), instance 0" in out
    assert "+2.4852" in out and "+0.90251" in out  # INS_ACCOFFS_Y, INS_ACCSCAL_Y
    assert main(["compare", str(tmp_path / "cal.yaml"), str(log), "--instance", "1"]) == 0
    assert "+0.2437" in capsys.readouterr().out  # INS_ACC2OFFS_Y


def test_compare_reads_the_real_px4_logs(tmp_path, capsys):
    save_calibration(Calibration.identity(accel_device_id=1310996), tmp_path / "cal.yaml")
    first = shared_path("real/px4_ulog/sample.ulg")
    assert main(["compare", str(tmp_path / "cal.yaml"), str(first)]) == 0
    out = capsys.readouterr().out
    assert "px4 parameters (493), instance 0" in out and "-0.2025, +0.3496, -0.6137" in out
    second = shared_path("real/px4_ulog/sample_logging_tagged_and_default_params.ulg")
    assert main(["compare", str(tmp_path / "cal.yaml"), str(second)]) == 0
    out = capsys.readouterr().out
    assert "instance 1" in out and "-0.0259, -0.0183, +0.0758" in out  # chosen by CAL_ACC1_ID = accel_device_id


def test_compare_refuses_what_is_no_parameter_file(tmp_path, capsys):
    save_calibration(Calibration.identity(), tmp_path / "cal.yaml")
    (tmp_path / "x.param").write_text("just some words here and there\n")
    assert main(["compare", str(tmp_path / "cal.yaml"), str(tmp_path / "x.param")]) == 1
    assert "accel-calib: error:" in capsys.readouterr().err
    (tmp_path / "y.param").write_text("SOME_PARAM,1\n")
    assert main(["compare", str(tmp_path / "cal.yaml"), str(tmp_path / "y.param")]) == 1
    assert "cannot tell PX4" in capsys.readouterr().err
