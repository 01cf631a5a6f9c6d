"""accel-calib fit --prior: a vehicle that cannot be turned over recalibrated from poses near level and its
calibration file. The file written says per parameter whether the poses or the prior set it; a prior
that cannot serve, and the same poses without a prior, are refused in one line."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from accel_calibration import MG, load_calibration, save_calibration
from accel_calibration.cli.main import main

from helpers.one_line import assert_one_error_line
from helpers.prior_sessions import level_poses, sensor_and_old_calibration


def write_table(path, raw):
    path.write_text("ax,ay,az\n" + "".join(f"{a:.9f},{b:.9f},{c:.9f}\n" for a, b, c in raw))


@pytest.fixture
def level_session(tmp_path):
    """8 poses within 30 deg of level of a sensor whose z bias moved 8 mg, and its old calibration's file."""
    rng, moved, old = sensor_and_old_calibration(3)
    write_table(tmp_path / "level.csv", level_poses(moved, rng))
    save_calibration(old, tmp_path / "old.yaml")
    return tmp_path, moved, old


def run_fit(capsys, *args):
    code = main(["fit", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


def test_fit_with_the_prior_brings_the_z_bias_back_and_the_file_says_where_each_parameter_came_from(
        level_session, capsys):
    tmp_path, moved, old = level_session
    code, out, err = run_fit(capsys, tmp_path / "level.csv", "--prior", tmp_path / "old.yaml",
                             "-o", tmp_path / "new.yaml")
    assert code == 0, err
    new = load_calibration(tmp_path / "new.yaml")
    assert abs(new.bias[2] - moved.bias_mps2[2]) / MG < 1.0
    assert abs(old.bias[2] - moved.bias_mps2[2]) / MG > 7.0
    sources = yaml.safe_load((tmp_path / "new.yaml").read_text())["accel_calibration"]["parameter_sources"]
    assert sources["prior"] == str(tmp_path / "old.yaml")
    parameters = sources["parameters"]
    assert [parameters[name]["from"] for name in ("b_x", "b_y", "b_z", "M_zx", "M_zy")] == \
        ["poses", "poses", "poses", "prior", "prior"]
    # Left to the prior: its sigma, in the file as the new uncertainty too.
    assert parameters["M_zx"]["sigma"] == pytest.approx(old.matrix_sigma[2, 0], rel=0.05)
    assert new.matrix_sigma[2, 0] == pytest.approx(old.matrix_sigma[2, 0], rel=0.05)
    assert new.bias_sigma[2] < 0.1 * parameters["b_z"]["prior_sigma"]
    assert "M_zx" in out and "from prior" in out and "from poses" in out


def test_the_same_poses_without_a_prior_are_refused(level_session, capsys):
    tmp_path, _, _ = level_session
    code, _, err = run_fit(capsys, tmp_path / "level.csv", "-o", tmp_path / "new.yaml")
    assert_one_error_line(code, err, "needs at least 9 poses, got 8")
    assert not (tmp_path / "new.yaml").exists()


def one_line_refusal(capsys, tmp_path, prior_file, *extra):
    code, _, err = run_fit(capsys, tmp_path / "level.csv", "--prior", prior_file, *extra, "-o", tmp_path / "new.yaml")
    assert_one_error_line(code, err)
    assert not (tmp_path / "new.yaml").exists()
    return err


def test_a_prior_of_another_model_or_without_uncertainty_is_refused_in_one_line(level_session, capsys):
    tmp_path, _, old = level_session
    save_calibration(old.replace(bias_sigma=None, matrix_sigma=None), tmp_path / "bare.yaml")
    assert "uncertainty" not in (tmp_path / "bare.yaml").read_text()
    err = one_line_refusal(capsys, tmp_path, tmp_path / "bare.yaml")
    assert "the prior has no uncertainty" in err and "bare.yaml" in err
    err = one_line_refusal(capsys, tmp_path, tmp_path / "old.yaml", "--model", "six")
    assert "the prior is model sphere9 and the fit model six" in err
    err = one_line_refusal(capsys, tmp_path, tmp_path / "old.yaml", "--model", "reference12")
    assert "--prior fits the sphere models" in err
    err = one_line_refusal(capsys, tmp_path, tmp_path / "absent.yaml")
    assert "absent.yaml" in err


def test_a_loose_prior_is_refused_by_a_named_gate(level_session, capsys):
    """A prior on M 30x looser than the old calibration's: what the level poses do not see is then known to
    no better than the bounds; the sigma gate names the parameter and the orientation that would help."""
    tmp_path, _, old = level_session
    save_calibration(old.replace(matrix_sigma=old.matrix_sigma * 30.0), tmp_path / "loose.yaml")
    err = one_line_refusal(capsys, tmp_path, tmp_path / "loose.yaml")
    assert "(gate sigma: " in err and "above" in err and "would lower it most" in err, err


def test_a_prior_without_drift_against_a_moved_bias_is_refused_in_one_line(level_session, capsys):
    tmp_path, _, _ = level_session
    err = one_line_refusal(capsys, tmp_path, tmp_path / "old.yaml", "--prior-bias-drift", "0")
    assert "the poses disagree with the prior" in err
    err = one_line_refusal(capsys, tmp_path, tmp_path / "old.yaml", "--prior-bias-drift", "-1")
    assert "--prior-bias-drift must be" in err


def test_poses_far_off_the_sphere_are_refused_by_the_residual_gate(level_session, capsys):
    """Level poses taken while moving (30 mg of error each) fit the prior, but off the sphere by more than
    the residual gate allows: refused, as /calibrate would."""
    tmp_path, moved, _ = level_session
    rng = np.random.default_rng(12)
    write_table(tmp_path / "level.csv", level_poses(moved, rng, 12) + rng.normal(0.0, 30 * MG, (12, 3)))
    err = one_line_refusal(capsys, tmp_path, tmp_path / "old.yaml")
    assert "(gate residual: rms" in err, err
