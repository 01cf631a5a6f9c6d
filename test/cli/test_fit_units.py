"""`fit` reads a table in the units it is told (--units) and refuses, in one line, a table whose pose
magnitudes say otherwise (median |a| far from gravity), as replay does for a stream: a table in m/s^2
read as g gave a dividing-head calibration with scales of -9.9 and exit 0."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from accel_calibration.core.dividing_head import DividingHeadModel

from helpers.one_line import assert_one_error_line, run_main

G = 9.80665
ALPHA_DEG = np.tile(np.arange(8) * 45.0, 3)
BETA_DEG = np.repeat([0.0, 45.0, 90.0], 8)
IDEAL_HEAD = np.concatenate([np.ones(3), np.zeros(12)])  # scale 1, no bias, no misalignment or tilt error


def head_table_g():
    """The 24 positions of Gao et al.'s protocol as an ideal sensor reads them, in g."""
    return DividingHeadModel.from_angles(np.radians(ALPHA_DEG), np.radians(BETA_DEG)).predict(IDEAL_HEAD)


def write_head_table(path, accel):
    lines = ["alpha_deg,beta_deg,ax,ay,az"] + [f"{a!r},{b!r},{x!r},{y!r},{z!r}" for a, b, (x, y, z)
                                               in zip(ALPHA_DEG.tolist(), BETA_DEG.tolist(), accel.tolist())]
    path.write_text("\n".join(lines) + "\n")


def write_pose_table(path, accel):
    path.write_text("ax,ay,az\n" + "\n".join(",".join(repr(v) for v in row) for row in accel.tolist()) + "\n")


def sphere_table_g(seed, count=20):
    directions = np.random.default_rng(seed).normal(size=(count, 3))
    return directions / np.linalg.norm(directions, axis=1, keepdims=True)


@pytest.mark.parametrize("model", ["dividing-head", "sphere9"])
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(scale=st.sampled_from([G, 16384.0, 1.0 / G, 0.5]), seed=st.integers(0, 1000))
def test_a_table_in_other_units_than_said_is_refused_in_one_line(tmp_path, model, scale, seed):
    """A table in g read as g fits; the same table scaled (m/s^2 read as g, counts, g read as m/s^2 via
    the 1/g case, half scale) is refused naming the median |a|, and no output is written."""
    table, output = tmp_path / f"{seed}.csv", tmp_path / f"{seed}.yaml"
    accel_g = head_table_g() if model == "dividing-head" else sphere_table_g(seed)
    write = write_head_table if model == "dividing-head" else write_pose_table
    write(table, accel_g * scale)
    code, err = run_main(["fit", table, "--model", model, "--units", "g", "-o", output])
    assert_one_error_line(code, err, "median |a|", "--units g", "implausible")
    assert not output.exists()


@pytest.mark.parametrize("model", ["dividing-head", "sphere9"])
def test_a_table_in_the_units_said_fits(tmp_path, model):
    accel_g = head_table_g() if model == "dividing-head" else sphere_table_g(1)
    write = write_head_table if model == "dividing-head" else write_pose_table
    for units, accel in (("g", accel_g), ("mps2", accel_g * G)):
        table, output = tmp_path / f"{units}.csv", tmp_path / f"{units}.yaml"
        write(table, accel)
        code, err = run_main(["fit", table, "--model", model, "--units", units, "-o", output])
        assert code == 0 and output.exists(), err
