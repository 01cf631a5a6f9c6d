"""/calibrate does each piece of work once: with auto_calibrate on, the feed that starts /calibrate may
auto-calibrate from the poses held (a cold fit and the gyro fit) before /calibrate judges those same
poses; the cold fit and the gyro's verdict are then taken from that, not computed again, and the answer
is the one /calibrate gives when nothing was auto-calibrated before it."""
from __future__ import annotations

import numpy as np
import pytest

import accel_calibration.core.session as session_module
from accel_calibration.core.settings import Settings
from accel_calibration.live.calibration_work import LiveCalibration

from helpers.session_doors import LogLines, buffer_messages
from helpers.session_streams import stream

ERRORS, SAMPLES = stream(seed=3, poses=16)


def calibrate_after(cut: int, folder, auto: bool, monkeypatch) -> tuple[LiveCalibration, LogLines, str, int]:
    """The stream fed up to `cut - 3000`, then /calibrate with the samples up to `cut` waiting in the ring:
    (the work, its log, the answer with its folder taken out, the gyro fits /calibrate ran)."""
    log = LogLines()
    live = LiveCalibration(Settings(auto_calibrate=auto), folder / "cal.yaml", log)
    live.start()
    buffer_messages(live, SAMPLES, 0, cut - 3000)
    live.feed()
    buffer_messages(live, SAMPLES, cut - 3000, cut)
    calls = []
    fit_gyro = session_module.fit_gyro

    def counted(*args, **kwargs):
        calls.append(1)
        return fit_gyro(*args, **kwargs)

    monkeypatch.setattr(session_module, "fit_gyro", counted)
    success, answer = live.calibrate()
    monkeypatch.setattr(session_module, "fit_gyro", fit_gyro)
    assert success, answer
    return live, log, answer.replace(str(folder), "<folder>"), len(calls)


# Cuts where the stream stops moving, after a pose ended in the samples /calibrate's own feed takes.
@pytest.mark.parametrize("cut", [8250, 9075, 9625])
def test_one_calibrate_runs_the_gyro_fit_once_and_answers_as_without_auto_calibration(cut, tmp_path, monkeypatch):
    (tmp_path / "auto").mkdir()
    (tmp_path / "asked").mkdir()
    auto, auto_log, auto_answer, auto_fits = calibrate_after(cut, tmp_path / "auto", True, monkeypatch)
    asked, _, asked_answer, asked_fits = calibrate_after(cut, tmp_path / "asked", False, monkeypatch)
    # The case this is about: /calibrate's own feed auto-calibrated from the poses it then judged.
    assert any(text.startswith("auto-calibrated") for _, text in auto_log.lines)
    assert asked_fits == 1
    assert auto_fits == 1
    assert auto_answer == asked_answer
    assert auto.store.calibration.gyro_matrix is not None
    np.testing.assert_array_equal(auto.store.calibration.gyro_matrix, asked.store.calibration.gyro_matrix)
    np.testing.assert_array_equal(auto.store.calibration.bias, asked.store.calibration.bias)
