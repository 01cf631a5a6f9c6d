"""The LSB of quantised samples is found per axis, and nothing is found in samples on no grid; a pose's mean
quantised with noise below the LSB gets at least LSB^2/12 of variance whatever its sample count."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from accel_calibration.core.pose import Pose
from accel_calibration.core.quantisation import quantisation_steps, with_quantisation


@settings(max_examples=60, deadline=None)
@given(lsb=st.floats(5e-4, 0.5), offset=st.floats(-0.5, 0.5), noise_in_lsb=st.floats(0.05, 5.0),
       seed=st.integers(0, 2**31))
def test_the_lsb_of_quantised_samples_is_found_on_every_axis(lsb, offset, noise_in_lsb, seed):
    rng = np.random.default_rng(seed)
    truth = np.array([0.3, -9.7, 1.2]) + rng.normal(0.0, noise_in_lsb * lsb, (3000, 3))
    truth[1000:2000] += rng.normal(0.0, 20 * lsb, 3)  # another pose: levels far apart
    truth[2000:2200] += np.linspace(-50 * lsb, 50 * lsb, 200)[:, None]  # the move between them sweeps the levels
    quantised = (np.round(truth / lsb) * lsb + offset).astype(np.float32).astype(float)  # as a float32 log holds it
    steps = quantisation_steps(quantised)
    assert np.allclose(steps, lsb, rtol=1e-3), (steps, lsb)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31), noise=st.floats(1e-5, 0.1))
def test_samples_on_no_grid_have_no_lsb(seed, noise):
    rng = np.random.default_rng(seed)
    samples = np.array([0.3, -9.7, 1.2]) + rng.normal(0.0, noise, (5000, 3))
    assert np.all(quantisation_steps(samples) == 0)


def test_a_mean_quantised_below_its_noise_keeps_lsb_squared_over_12():
    lsb = 0.04
    pose = Pose(accel_mps2=np.array([0.0, 0.0, 9.8]), accel_cov=np.diag([1e-8, (2 * lsb) ** 2, 0.0]), samples=400,
                start_ns=0, end_ns=1)
    (checked,) = with_quantisation([pose], np.full(3, lsb))
    mean_variance = np.diag(checked.accel_cov) / pose.samples
    assert np.isclose(mean_variance[0], 1e-8 / 400 + lsb**2 / 12)  # below the LSB: LSB^2/12 on the mean
    assert np.isclose(mean_variance[1], ((2 * lsb) ** 2 + lsb**2 / 12) / 400)  # above it: averages down
    assert np.isclose(mean_variance[2], lsb**2 / 12)
