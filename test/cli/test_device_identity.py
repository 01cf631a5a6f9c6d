"""The IMU's device ID is a field of its own (accel_device_id, gyro_device_id): carried from the log's
readers through replay to the calibration file and compared by the fleet as a number. sensor_id is text for
people: a sensor_id that merely looks like "px4 device 5" makes no device; only a file written before the
field existed is read by its sensor_id, and then with a line saying so."""
from __future__ import annotations

import numpy as np

from accel_calibration.bag.replay import ReplaySource
from accel_calibration.cli.main import main
from accel_calibration.core.calibration import Calibration
from accel_calibration.io.autopilot_params import parse_parameter_text
from accel_calibration.io.calibration_file import load_calibration, save_calibration

DEVICE = 1310988


def source(sensor_id: str, device: int | None) -> ReplaySource:
    return ReplaySource(path="log.ulg", imu_topic="sensor_accel", temperature_topic=None, messages=1,
                        duration_s=1.0, start_ns=0, frame_id="", sensor_id=sensor_id, recording=None,  # type: ignore[arg-type]
                        accel_device_id=device)


def test_two_imus_are_one_device_by_their_ids_not_their_names():
    combined, instance = source(f"px4 device {DEVICE}", DEVICE), source("sensor_accel 1", DEVICE)
    assert combined.same_device(instance) and instance.same_device(combined)
    assert not combined.same_device(source(f"px4 device {DEVICE}", DEVICE + 1))
    # Names alike, no device said: not known to be one device.
    assert not source("px4 device 5", None).same_device(source("px4 device 5", None))


def exported_ids(tmp_path, path) -> tuple[int, dict[str, float], str]:
    out = tmp_path / "p.params"
    code = main(["export", str(path), "--to", "px4", "--instance", "2", "-o", str(out)])
    return code, parse_parameter_text(out.read_text(), "p").values if out.exists() else {}, ""


def test_a_sensor_id_that_looks_like_a_device_makes_no_device(tmp_path, capsys):
    path = tmp_path / "cal.yaml"
    save_calibration(Calibration(bias=[0.1, 0.2, 0.3], matrix=np.eye(3), gyro_bias_radps=[0.01, 0.02, 0.03],
                                 sensor_id=f"px4 device {DEVICE}"), path)
    assert load_calibration(path).accel_device_id is None
    code, values, _ = exported_ids(tmp_path, path)
    assert code == 0
    assert values.get("CAL_ACC2_ID") != DEVICE and values.get("CAL_GYRO2_ID") != DEVICE
    assert capsys.readouterr().err == ""


def test_the_device_field_is_the_device_whatever_sensor_id_says(tmp_path):
    path = tmp_path / "cal.yaml"
    save_calibration(Calibration(bias=[0.1, 0.2, 0.3], matrix=np.eye(3), gyro_bias_radps=[0.01, 0.02, 0.03],
                                 sensor_id="left wing IMU", accel_device_id=DEVICE, gyro_device_id=DEVICE + 1), path)
    code, values, _ = exported_ids(tmp_path, path)
    assert code == 0
    assert values["CAL_ACC2_ID"] == DEVICE and values["CAL_GYRO2_ID"] == DEVICE + 1


def test_an_older_file_naming_its_device_in_sensor_id_is_read_with_a_line_saying_so(tmp_path, capsys):
    for sensor_id in (f"px4 device {DEVICE}", f"ardupilot accel {DEVICE}", str(DEVICE)):
        path = tmp_path / "older.yaml"
        save_calibration(Calibration(bias=[0.1, 0.2, 0.3], matrix=np.eye(3), gyro_bias_radps=[0.01, 0.02, 0.03],
                                     sensor_id=sensor_id), path)
        # As written before the device had a field of its own: no device_id keys at all.
        path.write_text("".join(line for line in path.read_text().splitlines(keepends=True)
                                if "device_id:" not in line))
        code, values, _ = exported_ids(tmp_path, path)
        assert code == 0
        assert values["CAL_ACC2_ID"] == DEVICE and values["CAL_GYRO2_ID"] == DEVICE
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "older.yaml" in err[0] and "sensor_id" in err[0] and "accel_device_id" in err[0]
