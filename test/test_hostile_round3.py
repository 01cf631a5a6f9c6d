"""Hostile round three (issue 25): no result lost, nothing written where it must not be, no secret
printed, no hang. One test (or a few) per item of the issue, each failing before its fix."""
from __future__ import annotations

import os
import sqlite3
import stat
import time

import numpy as np
import pytest

from accel_calibration.cli.main import main
from accel_calibration.core.calibration import MAX_IDENTIFIER_CHARS, Calibration
from accel_calibration.core.errors import CalibrationError
from accel_calibration.io import calibration_file
from accel_calibration.io.calibration_file import load_calibration, save_calibration


# --- 1. a file the loader refuses is never put in place --------------------------------------------------

@pytest.mark.parametrize("frame_id", ["imu_link" * 140_000, "imu\x00link\n\x1b[31m", "\udcff" * 300])
def test_a_huge_or_unprintable_frame_id_still_saves_a_file_that_loads(tmp_path, frame_id):
    path = tmp_path / "cal.yaml"
    calibration = Calibration.identity(frame_id=frame_id, sensor_id=frame_id)
    save_calibration(calibration, path)
    assert path.stat().st_size < 4096
    loaded = load_calibration(path)
    assert loaded == calibration
    for kept in (loaded.frame_id, loaded.sensor_id):
        assert len(kept) <= MAX_IDENTIFIER_CHARS and kept.isprintable()
    assert loaded.frame_id.startswith(frame_id[:3].replace("\x00", "?").replace("\udcff", "?"))


def test_a_calibration_whose_file_would_be_refused_is_not_written(tmp_path, monkeypatch):
    path = tmp_path / "cal.yaml"
    save_calibration(Calibration.identity(frame_id="old"), path)
    before = path.read_bytes()
    text = calibration_file.calibration_to_yaml(Calibration.identity())
    monkeypatch.setattr(calibration_file, "calibration_to_yaml",
                        lambda c: text + "#" + "x" * calibration_file.MAX_CALIBRATION_BYTES + "\n")
    with pytest.raises(CalibrationError, match="not written.*KiB"):
        save_calibration(Calibration.identity(frame_id="new"), path)
    monkeypatch.setattr(calibration_file, "calibration_to_yaml", lambda c: text.replace("model: sphere9", "model: x"))
    with pytest.raises(CalibrationError, match="not written.*would not load back"):
        save_calibration(Calibration.identity(frame_id="new"), path)
    assert path.read_bytes() == before
    assert load_calibration(path).frame_id == "old"
