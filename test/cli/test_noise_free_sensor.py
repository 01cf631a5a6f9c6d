"""A noise-free simulated sensor (every still sample exactly its predecessor): the frozen-run rule keeps such
runs out (a live MEMS part always shows noise; a stuck driver does not), so replay refuses, and says so
(not "hardly ever still"), with `-p` values that do calibrate a noise-free stream, to its truth."""
from __future__ import annotations

import re
import shlex

import numpy as np

from accel_calibration.core.units import MG
from accel_calibration.io.calibration_file import load_calibration
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, rotation_with_up, spread_orientations

from helpers.one_line import assert_one_error_line, run_main


def noise_free_recording(path):
    rng = np.random.default_rng(4)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.0)
    errors = SensorErrors(bias_mps2=errors.bias_mps2, matrix=errors.matrix, noise_mps2=0.0, gyro_noise_radps=0.0,
                          gyro_bias_radps=errors.gyro_bias_radps)
    rotations = [rotation_with_up([0.0, 0.0, 1.0]), *spread_orientations(13, rng)]
    s = SyntheticImu(errors, rotations, dwell_s=2.5, move_s=0.8, rate_hz=100.0, seed=4).samples()
    rows = [f"{t},{','.join(repr(float(v)) for v in (*a, *g))}" for t, a, g in zip(s.t_ns, s.accel_raw, s.gyro_raw)]
    path.write_text("t_ns,ax,ay,az,gx,gy,gz\n" + "\n".join(rows) + "\n")
    return errors


def test_a_noise_free_sensor_is_refused_for_what_it_is_and_the_suggestion_calibrates_it(tmp_path):
    recording = tmp_path / "noise_free.csv"
    truth = noise_free_recording(recording)
    output = tmp_path / "cal.yaml"
    code, err = run_main(["replay", recording, "-o", output])
    assert_one_error_line(code, err, "bit for bit", "frozen_samples")
    assert "hardly ever still" not in err and "static.max_noise_mg" not in err, err
    suggested = re.search(r"noise-free sensor[^:]*: ((?:-p \S+ ?)+)", err)
    assert suggested, err
    code, err = run_main(["replay", recording, "-o", output, *shlex.split(suggested.group(1))])
    assert code == 0, err
    calibration = load_calibration(output)
    assert np.max(np.abs(calibration.bias - truth.bias_mps2)) < 0.001 * MG
    assert np.max(np.abs(calibration.matrix - truth.matrix)) < 1e-6
