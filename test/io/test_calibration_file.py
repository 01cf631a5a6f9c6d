"""Calibration files: round trips, refusals with one clear reason, atomic replacement."""
import os

import numpy as np
import pytest
import yaml

from accel_calibration import Calibration, CalibrationError, fit, save_calibration
from accel_calibration.io.calibration_file import FORMAT_VERSION, calibration_to_dict, load_calibration


def fitted_calibration():
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(15, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    directions[:6] = np.vstack([np.eye(3), -np.eye(3)])
    raw = 9.80665 * directions * [1.01, 0.98, 1.02] + [0.2, -0.3, 0.1] + rng.normal(0, 0.002, (15, 3))
    return fit(raw, frame_id="imu_link").calibration


def test_round_trip_is_exact(tmp_path):
    cal = fitted_calibration()
    path = tmp_path / "cal.yaml"
    save_calibration(cal, path)
    again = load_calibration(path)
    assert again == cal
    np.testing.assert_array_equal(again.apply([[1.0, 2.0, 9.0]]), cal.apply([[1.0, 2.0, 9.0]]))


def test_keys_other_tools_read(tmp_path):
    cal = fitted_calibration()
    save_calibration(cal, tmp_path / "cal.yaml")
    body = yaml.safe_load((tmp_path / "cal.yaml").read_text())["accel_calibration"]
    assert body["model"] == "sphere9" and body["gravity"] == 9.80665
    assert len(body["bias"]) == 3 and np.array(body["matrix"]).shape == (3, 3)
    assert set(body["quality"]) >= {"residual_rms_mg", "residual_max_mg", "poses"}
    assert body["quality"]["poses"] == 15 and body["format_version"] == 1  # 2 only with a warm-up's spline block


def _write(path, body):
    path.write_text(yaml.safe_dump({"accel_calibration": body}))
    return path


@pytest.mark.parametrize(
    "change, match",
    [
        (dict(format_version=FORMAT_VERSION + 1), "newer accel_calibration"),
        (dict(bias=[0.0, 1.0]), r"bias must have shape \(3,\)"),
        (dict(bias=[0.0, "x", 1.0]), "bias must be numbers"),
        (dict(matrix=[[1, 0, 0], [0, 1, 0]]), r"matrix must have shape \(3, 3\)"),
        (dict(matrix=[[0, 0, 0], [0, 0, 0], [0, 0, 0]]), "singular"),
        (dict(bias=[float("nan"), 0, 0]), "finite"),
        (dict(model="magic"), "unknown model"),
        (dict(gravity=-1), "gravity"),
        (dict(gravity="9.8"), "gravity must be a finite number"),
        (dict(quality="good"), "quality must be a mapping"),
    ],
)
def test_bad_files_are_refused_with_a_reason(tmp_path, change, match):
    body = calibration_to_dict(fitted_calibration())["accel_calibration"]
    body.update(change)
    path = _write(tmp_path / "cal.yaml", body)
    with pytest.raises(CalibrationError, match=match):
        load_calibration(path)


@pytest.mark.parametrize(
    "content, match",
    [
        (b"", "not an accel_calibration file"),
        (b"imu_calibration: {}\n", "not an accel_calibration file"),
        (b"accel_calibration: {model: sphere9}\n", "missing key 'bias'"),
        (b"accel_calibration: [1, 2\n", "not valid YAML"),
        (bytes(range(256)), "binary"),
    ],
)
def test_foreign_and_corrupt_files(tmp_path, content, match):
    path = tmp_path / "cal.yaml"
    path.write_bytes(content)
    with pytest.raises(CalibrationError, match=match):
        load_calibration(path)


def test_missing_file(tmp_path):
    with pytest.raises(CalibrationError, match="not found"):
        load_calibration(tmp_path / "absent.yaml")


def test_failed_write_leaves_the_old_file_whole(tmp_path, monkeypatch):
    """A full disk during the write (ENOSPC from fsync, as a real full disk reports it): the old file
    stays byte-for-byte and no temp file is left behind. (Directory permissions can't be used: CI is root.)"""
    import errno

    import accel_calibration.io.calibration_file as calibration_file

    path = tmp_path / "cal.yaml"
    save_calibration(fitted_calibration(), path)
    before = path.read_bytes()

    def disk_full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(calibration_file.os, "fsync", disk_full)
    with pytest.raises(CalibrationError, match="cannot write .*No space left"):
        save_calibration(Calibration.identity(), path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["cal.yaml"]


def test_failed_write_into_missing_directory(tmp_path):
    with pytest.raises(CalibrationError, match="cannot write"):
        save_calibration(Calibration.identity(), tmp_path / "no" / "such" / "cal.yaml")


def test_calibration_is_immutable():
    cal = Calibration.identity()
    with pytest.raises(ValueError):
        cal.bias[0] = 1.0
    with pytest.raises(AttributeError):
        cal.model = "six"


@pytest.mark.parametrize("field, uncertainty", [
    ("uncertainty.bias", {"bias": [0.001, -0.001, 0.001]}),
    ("uncertainty.matrix", {"matrix": [[1e-4, 0, 0], [0, 1e-4, 0], [0, 0, -1e-4]]}),
])
def test_a_negative_sigma_is_refused_naming_the_field(tmp_path, field, uncertainty):
    body = calibration_to_dict(fitted_calibration())["accel_calibration"]
    body["uncertainty"] = uncertainty
    path = _write(tmp_path / "cal.yaml", body)
    with pytest.raises(CalibrationError, match=field.replace(".", r"\.") + ".*negative") as caught:
        load_calibration(path)
    assert "\n" not in str(caught.value)
