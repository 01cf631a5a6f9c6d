"""A temperature model's fit honours the caller's outlier test and pose noise: the room-temperature (base)
calibration it learns the drift against is fitted with the same options, not the defaults."""
from __future__ import annotations

import numpy as np

from accel_calibration import fit
from accel_calibration.core.fit_result import OutlierOptions
from accel_calibration.core.temperature_models import TemperatureOptions

G = 9.80665
TILTED = np.array([[1, 1, 1], [-1, -1, 1], [1, -1, -1], [-1, 1, -1], [1, -1, 1], [-1, 1, 1]], float) / np.sqrt(3)
DIRECTIONS = np.vstack([np.eye(3), -np.eye(3), TILTED])
MATRIX = np.array([[1.01, 0.0, 0.0], [0.003, 0.99, 0.0], [-0.002, 0.004, 1.005]])
BIAS = np.array([0.3, -0.2, 0.25])


def raw_of(directions, bias=BIAS):
    return np.linalg.solve(MATRIX, G * directions.T).T + bias


def segmented_poses(off_mg: float):
    """Twelve orientations at 20 degC and at 30 degC (no drift); one room pose `off_mg` off the sphere."""
    room = raw_of(DIRECTIONS)
    room[4] *= 1.0 + off_mg * 1e-3
    warm = raw_of(DIRECTIONS)
    return np.vstack([room, warm]), np.r_[np.full(len(room), 20.0), np.full(len(warm), 30.0)], room


def test_outlier_test_off_is_off_for_the_room_temperature_calibration_too():
    accel, temps, room = segmented_poses(off_mg=20.0)
    never = OutlierOptions(threshold_mg=0.0)
    options = TemperatureOptions(model="segmented", segment_width_degc=10.0, reference_degc=20.0)
    with_model = fit(accel, temperature_degc=temps, temperature_model="segmented", temperature_options=options,
                     outlier_options=never)
    room_alone = fit(room, outlier_options=never)
    assert with_model.success and room_alone.success, (with_model.message, room_alone.message)
    assert not room_alone.outliers
    # The room calibration is the fit of every room pose, as asked: the off pose pulls it (by ~7 mg), where
    # the default outlier test would have left that pose out silently.
    np.testing.assert_allclose(with_model.calibration.bias, room_alone.calibration.bias, atol=1e-9)
    np.testing.assert_allclose(with_model.calibration.matrix, room_alone.calibration.matrix, atol=1e-12)
    left_out = fit(room)
    assert left_out.outliers and np.max(np.abs(left_out.calibration.bias - room_alone.calibration.bias)) > 1e-4


def test_the_room_temperature_calibration_weighs_the_poses_by_their_noise_as_asked():
    rng = np.random.default_rng(4)
    accel, temps, _ = segmented_poses(off_mg=0.0)
    sigma = np.where(np.arange(len(accel)) % 3 == 0, 0.02, 0.0005)  # some poses forty times noisier
    accel = accel + rng.normal(0.0, 1.0, accel.shape) * sigma[:, None]
    never = OutlierOptions(threshold_mg=0.0)
    options = TemperatureOptions(model="segmented", segment_width_degc=10.0, reference_degc=20.0)
    with_model = fit(accel, temperature_degc=temps, temperature_model="segmented", temperature_options=options,
                     outlier_options=never, pose_sigma_mps2=sigma)
    room = temps == 20.0
    weighted = fit(accel[room], outlier_options=never, pose_sigma_mps2=sigma[room])
    unweighted = fit(accel[room], outlier_options=never)
    assert with_model.success and weighted.success, (with_model.message, weighted.message)
    np.testing.assert_allclose(with_model.calibration.bias, weighted.calibration.bias, atol=1e-9)
    assert np.max(np.abs(weighted.calibration.bias - unweighted.calibration.bias)) > 1e-4
