"""The node's watch of the calibration in force (core/watch.py), against a simulated truth: a sensor that
did not change never warns over many seeds, pose after pose as the node checks; a 5 mg bias shift on one
axis is reported with its axis within a 10-pose session; a calibration put in force restarts the count."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from accel_calibration.core.units import MG
from accel_calibration.core.watch import CalibrationWatch
from msg_tools.synthetic_imu import spread_orientations

from helpers.still_poses import fitted, poses_of, sensor

POSES = 10


def test_a_sensor_that_did_not_change_never_warns_pose_after_pose():
    # 0 warnings in 300 sessions of 10 looks each bounds the rate per session below 1 % (95 %, rule of three).
    warned, largest = 0, []
    for seed in range(300):
        errors, rng = sensor(1000 + seed)
        watch = CalibrationWatch()
        watch.restart(fitted(errors, rng))
        for pose in poses_of(errors, spread_orientations(POSES, rng), rng):
            warned += watch.add([pose]).moved
        assert watch.result is not None and len(watch.result.poses) == POSES
        largest.append(max(c.judgement.sigmas for c in watch.result.changes if c.judgement))
    assert warned == 0, warned
    assert 1.0 < float(np.median(largest)) < 3.5, np.median(largest)  # not so loose it could never fire


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_5_mg_bias_shift_is_reported_with_its_axis_within_ten_poses(axis):
    for seed in range(10):
        errors, rng = sensor(2000 + seed)
        watch = CalibrationWatch()
        watch.restart(fitted(errors, rng))
        assert "no still pose" in watch.state.text
        moved = dataclasses.replace(errors, bias_mps2=errors.bias_mps2 + 5 * MG * np.eye(3)[axis])
        first = None
        for count, pose in enumerate(poses_of(moved, spread_orientations(POSES, rng), rng), start=1):
            if watch.add([pose]).moved and first is None:
                first = count
        assert first is not None and first <= POSES
        assert watch.result is not None and [c.name for c in watch.result.moved] == [f"bias {'xyz'[axis]}"]
        change = watch.result.moved[0]
        assert abs(change.change - 5 * MG) < 4 * change.sigma and change.sigma < 0.5 * MG
        assert watch.state.text.startswith(f"bias {'xyz'[axis]} +")
        assert watch.state.text.split(" mg")[0].endswith(f"{change.change / MG:+.1f}")
        assert ": recalibrate" in watch.state.text


def test_a_calibration_put_in_force_restarts_the_poses_that_count():
    errors, rng = sensor(7)
    calibration = fitted(errors, rng)
    watch = CalibrationWatch()
    assert not watch.add(poses_of(errors, spread_orientations(3, rng), rng)).moved  # none in force: nothing
    assert watch.result is None
    watch.restart(calibration)
    moved = dataclasses.replace(errors, bias_mps2=errors.bias_mps2 + np.array([0.0, 20 * MG, 0.0]))
    assert watch.add(poses_of(moved, spread_orientations(POSES, rng), rng)).moved
    watch.restart(calibration)
    assert not watch.state.moved and watch.poses == []
    state = watch.add(poses_of(errors, spread_orientations(8, rng), rng))
    assert not state.moved and state.text.startswith("calibration holds (8 poses, ")


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_shift_while_the_watch_runs_is_reported_at_its_size(axis):
    """The calibration holds for a session of poses, then the bias moves 5 mg and the same orientations are
    held again: the figure is the shift's (within 1 mg), from the poses since it moved, not the shift
    diluted by the poses from before (which read +0.4 mg, then +1.5 mg 20 poses later)."""
    for seed in range(6):
        errors, rng = sensor(3000 + seed)
        watch = CalibrationWatch()
        watch.restart(fitted(errors, rng))
        orientations = spread_orientations(14, rng)
        for pose in poses_of(errors, orientations, rng):
            assert not watch.add([pose]).moved
        moved = dataclasses.replace(errors, bias_mps2=errors.bias_mps2 + 5 * MG * np.eye(3)[axis])
        after = poses_of(moved, orientations * 2, rng, first_ns=100 * 10**9)
        for pose in after:
            watch.add([pose])
        assert watch.state.moved and watch.result is not None
        changes = {c.name: c for c in watch.result.changes}
        change = changes[f"bias {'xyz'[axis]}"]
        assert abs(change.change - 5 * MG) < 1 * MG, (seed, change.change / MG)
        assert [c.name for c in watch.result.moved] == [f"bias {'xyz'[axis]}"], watch.state.text
        assert watch.state.text.startswith(f"bias {'xyz'[axis]} +{change.change / MG:.1f} mg")
        # Judged on the poses since the move: the first of them an orientation that sees the axis moved.
        watch_before = CalibrationWatch()
        watch_before.restart(watch.calibration)
        assert watch_before.add(poses_of(errors, orientations, rng)).moved is False
        assert watch_before.moved_since_ns is None
        assert after[0].start_ns <= watch.moved_since_ns <= after[len(orientations)].start_ns
        assert len(watch.result.poses) >= 2 * len(orientations) - 6
