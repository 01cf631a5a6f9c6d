"""Two writers of one calibration_file (two nodes, or a node and `accel-calib replay -o`): the file always
stays whole, and a node never overwrites, unnoticed, a file that changed since it loaded or saved it: the
save is refused with a WARN saying why, the file and the calibration in force stay as they are, the poses
are kept, and the same call again overwrites on purpose (auto_calibrate never does). Rewriting the same
bytes (a touch) is no change."""
from __future__ import annotations

import os

import pytest

from accel_calibration.core.settings import Settings
from accel_calibration.live.calibration_work import LiveCalibration

from helpers.session_doors import LogLines, buffer_messages
from helpers.session_streams import stream

_, FIRST = stream(seed=3, poses=16)
_, SECOND = stream(seed=5, poses=16)


def calibrated(path, samples):
    log = LogLines()
    live = LiveCalibration(Settings(), path, log)
    live.start()
    buffer_messages(live, samples, 0, len(samples.t_ns))
    success, message = live.calibrate()
    assert success, message
    return live, log


def rewrite_as_replay_would(path, text):
    scratch = path.with_name(".replay.tmp")
    scratch.write_text(text)
    os.replace(scratch, path)


@pytest.mark.parametrize("service", ["calibrate", "save"])
@pytest.mark.parametrize("writer", ["another node", "a replay"])
def test_a_file_changed_underneath_is_not_overwritten_unnoticed(tmp_path, service, writer):
    path = tmp_path / "cal.yaml"
    node, log = calibrated(path, FIRST)
    in_force = node.store.calibration
    if writer == "another node":
        calibrated(path, SECOND)
    else:
        rewrite_as_replay_would(path, path.read_text().replace("sensor_id:", "sensor_id: replayed #"))
    theirs = path.read_bytes()
    job = node.calibrate if service == "calibrate" else node.save
    success, message = job()
    assert not success
    assert "changed since this node" in message and "again" in message and "\n" not in message, message
    assert path.read_bytes() == theirs
    assert node.store.calibration is in_force
    assert node.status[0] == "warn" and "changed" in node.status[1]
    assert any(level == "warning" and "changed since this node" in text for level, text in log.lines)
    success, message = job()  # the same call again: on purpose
    assert success, message
    assert path.read_bytes() != theirs
    assert node.status == ("ok", "calibrated")  # the warning about the change is over


def test_the_same_bytes_rewritten_are_no_change(tmp_path):
    path = tmp_path / "cal.yaml"
    node, _ = calibrated(path, FIRST)
    rewrite_as_replay_would(path, path.read_text())
    success, message = node.save()
    assert success, message


def test_a_file_removed_underneath_is_written_again(tmp_path):
    """A removed file holds nothing to lose: calibration/save writes the calibration in force again."""
    path = tmp_path / "cal.yaml"
    node, _ = calibrated(path, FIRST)
    path.unlink()
    success, message = node.save()
    assert success and path.exists(), message


def test_auto_calibrate_never_overwrites_a_change_it_did_not_make(tmp_path):
    path = tmp_path / "cal.yaml"
    node, _ = calibrated(path, FIRST)
    rewrite_as_replay_would(path, path.read_text().replace("sensor_id:", "sensor_id: replayed #"))
    theirs = path.read_bytes()
    for _ in range(2):
        applied, message = node._apply(node.store.calibration, asked=False)
        assert not applied and "call /calibrate to overwrite it" in message, message
    assert path.read_bytes() == theirs
