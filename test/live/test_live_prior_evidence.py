"""The node's work without ROS (LiveCalibration) with use_calibration_in_force_as_prior: the calibration in
force is evidence, tested like any other before /calibrate leans on it. Another sensor's calibration in force
is refused, the file left as it was; the sensor's own serves, and what the level poses could not check is
said in /calibrate's answer, the log and the file."""
from __future__ import annotations

import yaml

from accel_calibration.core.settings import Settings
from accel_calibration.io.calibration_file import save_calibration
from accel_calibration.live.calibration_work import LiveCalibration

from helpers.prior_sessions import level_stream, sensor_and_old_calibration
from helpers.session_doors import LogLines, buffer_messages


def fed(live: LiveCalibration, samples, part: int = 300) -> LiveCalibration:
    live.start()
    for start in range(0, len(samples.t_ns), part):
        buffer_messages(live, samples, start, min(start + part, len(samples.t_ns)))
        live.feed()
    return live


def test_another_sensors_calibration_in_force_is_refused_as_the_prior_and_the_file_kept(tmp_path):
    """The sensor's own bias with another sensor's matrix (gains 1-3 % off): it was saved with the matrix kept."""
    rng, moved, old = sensor_and_old_calibration(0)
    _, _, other = sensor_and_old_calibration(50)
    save_calibration(old.replace(matrix=other.matrix), tmp_path / "cal.yaml")
    before = (tmp_path / "cal.yaml").read_text()
    live = fed(LiveCalibration(Settings(use_calibration_in_force_as_prior=True), tmp_path / "cal.yaml", LogLines()),
               level_stream(moved, rng, count=14, seed=0))
    assert live.watch.state.moved
    success, message = live.calibrate()
    assert not success and "the poses disagree with the prior" in message and " mg" in message, message
    assert (tmp_path / "cal.yaml").read_text() == before


def test_its_own_calibration_serves_and_what_was_not_checked_is_said_in_answer_log_and_file(tmp_path):
    rng, moved, old = sensor_and_old_calibration(3)
    save_calibration(old, tmp_path / "cal.yaml")
    log = LogLines()
    live = fed(LiveCalibration(Settings(use_calibration_in_force_as_prior=True), tmp_path / "cal.yaml", log),
               level_stream(moved, rng, seed=3))
    success, answer = live.calibrate()
    assert success, answer
    assert "kept from the prior, not checked" in yaml.safe_load(answer)["prior"], answer
    assert any(level == "warning" and "kept from the prior, not checked" in text for level, text in log.lines)
    # /diagnostics says it while that calibration is in force
    assert live.snapshot().values["prior_unchecked"].startswith("kept from the prior, not checked"), live.values()
    live.reset()
    assert live.values()["prior_unchecked"].startswith("kept from the prior, not checked")
    parameters = yaml.safe_load((tmp_path / "cal.yaml").read_text())["accel_calibration"]["parameter_sources"][
        "parameters"]
    assert parameters["M_zx"]["note"].startswith("kept from the prior, not checked"), parameters["M_zx"]
