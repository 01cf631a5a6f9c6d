"""accel-calib export / compare on hostile input: what the target or our loader refuses is refused in one
line with a nonzero exit and nothing written; topic names cannot inject YAML; numbers are parsed strictly."""
from __future__ import annotations

import struct
import warnings

import numpy as np
import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from accel_calibration.cli.main import main
from accel_calibration.core.calibration import Calibration
from accel_calibration.io.autopilot_params import parse_number
from accel_calibration.io.calibration_file import save_calibration
from accel_calibration.io.estimator_yaml import EstimatorFileError, NoiseFigures, kalibr_imu_yaml

NOISE = NoiseFigures(2e-3, 3e-4, 1.7e-4, 2e-5, 200.0)


def _one_line_error(capsys) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("accel-calib: error: "), captured.err
    assert "Traceback" not in captured.err
    return lines[0]


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
@pytest.mark.parametrize("changes, expected", [
    ({"bias": [50.0, 0, 0]}, "implausible"),
    ({"gyro_bias_radps": [1e6, 0, 0]}, "implausible"),
])
def test_export_refuses_what_our_loader_refuses_even_forced(target, changes, expected, tmp_path, capsys):
    calibration = Calibration.identity().replace(**changes)
    save_calibration(calibration, tmp_path / "cal.yaml")
    out = tmp_path / "out"
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", target, "-o", str(out), "--force"]) == 1
    assert expected in _one_line_error(capsys)
    assert not out.exists()


TOPICS_REFUSED = ["/imu\naccelerometer_noise_density: 99.0", "/imu#x", "[a", "*x", "", "/imu/", "/a//b",
                  "1imu", "/imu0 ", "imu: x", "/imu\r", "/\u00e9"]


@pytest.mark.parametrize("topic", TOPICS_REFUSED)
@pytest.mark.parametrize("target", ["kalibr", "openvins"])
def test_topic_names_that_are_not_ros_names_are_refused(topic, target, tmp_path, capsys):
    (tmp_path / "imu.yaml").write_text(kalibr_imu_yaml(NOISE, "/imu0"))
    save_calibration(Calibration.identity(), tmp_path / "cal.yaml")
    out = tmp_path / "out.yaml"
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", target, "--noise", str(tmp_path / "imu.yaml"),
                 f"--rostopic={topic}", "-o", str(out)]) == 1
    assert "not a valid ROS topic name" in _one_line_error(capsys)
    assert not out.exists()


@pytest.mark.parametrize("topic", TOPICS_REFUSED)
def test_the_kalibr_writer_noise_uses_refuses_them_too(topic):
    with pytest.raises(EstimatorFileError, match="not a valid ROS topic name"):
        kalibr_imu_yaml(NOISE, topic)


@pytest.mark.parametrize("topic", ["/imu0", "/camera/imu", "imu0", "~/imu", "/a_b/c9", "_private/x"])
def test_valid_topic_names_read_back_as_written(topic, tmp_path):
    document = yaml.safe_load(kalibr_imu_yaml(NOISE, topic, "from a file\nwith # and : [in] it\u2028x\x07"))
    assert document["rostopic"] == topic and document["accelerometer_noise_density"] == pytest.approx(2e-3)
    assert set(document) == {"accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density",
                             "gyroscope_random_walk", "rostopic", "update_rate"}


def _px4_file(tmp_path, **overrides: str):
    values = {"CAL_ACC0_XOFF": "0.1", "CAL_ACC0_YOFF": "0", "CAL_ACC0_ZOFF": "0", "CAL_ACC0_XSCALE": "1",
              "CAL_ACC0_YSCALE": "1", "CAL_ACC0_ZSCALE": "1", **overrides}
    path = tmp_path / "p.params"
    path.write_text("".join(f"1\t1\t{name}\t{value}\t9\n" for name, value in values.items()))
    return path


@pytest.mark.parametrize("overrides, expected", [
    ({"CAL_ACC0_XSCALE": "0"}, "CAL_ACC0_XSCALE = 0 is outside the range the autopilot accepts, 0.1..3"),
    ({"CAL_ACC0_YSCALE": "-1"}, "CAL_ACC0_YSCALE = -1 is outside"),
    ({"CAL_ACC0_ZSCALE": "1e38"}, "CAL_ACC0_ZSCALE = 1e+38 is outside"),
    ({"CAL_ACC0_XOFF": "1e300"}, "CAL_ACC0_XOFF"),
    ({"CAL_ACC0_XOFF": "1_0"}, "is not a number"),
    ({"CAL_ACC0_XOFF": "0x10"}, "is not a number"),
    ({"CAL_ACC0_XOFF": "\u0661"}, "is not a number"),
    ({"TC_A_ENABLE": "1", "TC_A0_TREF": "25", "TC_A0_TMIN": "40", "TC_A0_TMAX": "10"},
     "TC_A0_TMIN 40 above TC_A0_TMAX 10"),
])
def test_compare_refuses_what_px4_refuses(overrides, expected, tmp_path, capsys):
    save_calibration(Calibration.identity(), tmp_path / "cal.yaml")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy RuntimeWarning on the way
        assert main(["compare", str(tmp_path / "cal.yaml"), str(_px4_file(tmp_path, **overrides))]) == 1
    assert expected in _one_line_error(capsys)


@pytest.mark.parametrize("lines, expected", [
    (["INS_ACCOFFS_X,5"], "INS_ACCOFFS_X = 5 is outside"),
    (["INS_ACCSCAL_Y,0.5"], "INS_ACCSCAL_Y = 0.5 is outside"),
    (["INS_TCAL1_ENABLE,1", "INS_TCAL1_TMIN,50", "INS_TCAL1_TMAX,10"], "INS_TCAL1_TMIN 50 above INS_TCAL1_TMAX 10"),
])
def test_compare_refuses_what_ardupilot_refuses(lines, expected, tmp_path, capsys):
    save_calibration(Calibration.identity(), tmp_path / "cal.yaml")
    path = tmp_path / "a.param"
    path.write_text("\n".join(["INS_ACCOFFS_X,0.1", "INS_ACCOFFS_Y,0", "INS_ACCOFFS_Z,0", *lines]) + "\n")
    assert main(["compare", str(tmp_path / "cal.yaml"), str(path)]) == 1
    assert expected in _one_line_error(capsys)


def test_a_sensor_id_of_non_ascii_digits_is_no_device_id(tmp_path, capsys):
    save_calibration(Calibration.identity(sensor_id="\u00b2"), tmp_path / "cal.yaml")
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", "px4", "-o", str(tmp_path / "p.params")]) == 0
    assert "no device ID" in capsys.readouterr().out
    assert "CAL_ACC0_ID" not in (tmp_path / "p.params").read_text()
    assert main(["compare", str(tmp_path / "cal.yaml"), str(_px4_file(tmp_path))]) == 0
    assert "instance 0" in capsys.readouterr().out


def _ulog_parameter(type_name: str, name: str, value: bytes) -> bytes:
    key = f"{type_name} {name}".encode()
    body = bytes([len(key)]) + key + value
    return struct.pack("<HB", len(body), ord("P")) + body


def test_compare_refuses_a_ulog_whose_calibration_parameter_is_text(tmp_path, capsys):
    header = b"ULog\x01\x12\x35" + b"\x01" + struct.pack("<Q", 0)
    flags = bytes(16) + struct.pack("<3Q", 0, 0, 0)
    body = header + struct.pack("<HB", len(flags), ord("B")) + flags
    body += _ulog_parameter("char[4]", "CAL_ACC0_XOFF", b"0.10")
    for name in ("CAL_ACC0_YOFF", "CAL_ACC0_ZOFF"):
        body += _ulog_parameter("float", name, struct.pack("<f", 0.0))
    body += _ulog_parameter("int32_t", "CAL_ACC0_ID", struct.pack("<i", 1310988))
    (tmp_path / "odd.ulg").write_bytes(body)
    save_calibration(Calibration.identity(), tmp_path / "cal.yaml")
    assert main(["compare", str(tmp_path / "cal.yaml"), str(tmp_path / "odd.ulg")]) == 1
    assert "CAL_ACC0_XOFF is not a number" in _one_line_error(capsys)


def test_compare_reads_a_param_file_beginning_with_a_bom(tmp_path, capsys):
    save_calibration(Calibration.identity(), tmp_path / "cal.yaml")
    path = tmp_path / "a.param"
    path.write_bytes("\ufeffINS_ACCOFFS_X,0.1\nINS_ACCOFFS_Y,0\nINS_ACCOFFS_Z,0\n".encode())
    assert main(["compare", str(tmp_path / "cal.yaml"), str(path)]) == 0
    out = capsys.readouterr().out
    assert "ardupilot parameters (3)" in out and "+0.1000" in out
    # 0.1 m/s^2 on x against identity: 10.2 mg at worst
    assert f"worst {0.1 / 9.80665 * 1000:.3f} mg" in out


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_numbers_as_the_autopilots_write_them_parse_to_themselves(value):
    for text in (repr(value), f"{value:.9g}", f"{value:e}", f"{value:f}"):
        assert parse_number(text) == float(text)


@given(st.text(max_size=12))
def test_parse_number_takes_nothing_float_would_not_and_no_underscores_or_words(text):
    value = parse_number(text)
    if value is not None:
        assert value == float(text) and text.isascii()
        assert not any(c in text for c in "_ \t\n") and text.strip().lower() not in ("nan", "inf", "infinity")


def test_noise_kalibr_refuses_a_topic_that_is_no_ros_name_and_writes_nothing(tmp_path, capsys):
    rate = 100.0
    rng = np.random.default_rng(3)
    accel = rng.normal(0.0, 0.02, (6000, 3)) + [0.0, 0.0, 9.80665]
    gyro = rng.normal(0.0, 0.002, (6000, 3))
    data = np.column_stack([np.arange(6000) / rate, accel, gyro])
    np.savetxt(tmp_path / "still.csv", data, delimiter=",", fmt="%.9g", header="t,ax,ay,az,gx,gy,gz", comments="")
    out = tmp_path / "imu.yaml"
    assert main(["noise", str(tmp_path / "still.csv"), "--whole", "--kalibr", str(out),
                 "--rostopic=/imu\naccelerometer_noise_density: 99.0"]) == 1
    assert "not a valid ROS topic name" in _one_line_error(capsys)
    assert not out.exists()
