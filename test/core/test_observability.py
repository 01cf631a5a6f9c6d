"""The one rule of what poses can see (core/observability.py), shared by check, the watch and a fit's prior:
from poses near level a z bias is never told from a z gain, and the x and y gains are never seen through
tilts of a few degrees; from every face everything is seen; a change fitted in the observed directions
is the change itself where it is observed."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from accel_calibration.core.models import SphereModel
from accel_calibration.core.observability import observability
from accel_calibration.core.units import MG

from helpers.prior_sessions import G, near_level

SIX = SphereModel("six")
NAMES = ["bias x", "bias y", "bias z", "scale x", "scale y", "scale z"]
UNIT = np.array([1.0, 1.0, 1.0, 1.0 / G, 1.0 / G, 1.0 / G])


def seen_from(directions):
    _, jacobian = SIX.residual_and_jacobian(SIX.pack(np.zeros(3), np.eye(3)), G * directions, G)
    return observability(jacobian, NAMES, UNIT), jacobian


@settings(max_examples=40, deadline=None)
@given(degrees=st.floats(1.0, 30.0), count=st.integers(4, 20), seed=st.integers(0, 2**31))
def test_from_poses_near_level_bias_z_and_scale_z_are_never_told_apart(degrees, count, seed):
    seen, _ = seen_from(near_level(count, degrees, np.random.default_rng(seed)))
    assert not seen.observed[2] and not seen.observed[5], seen.observed
    assert any({2, 5} <= set(group) for group in seen.groups), seen.groups
    if degrees <= 5.0:  # a gain seen through 5 deg of tilt moves |a| by < 1 % of itself: not seen
        assert not seen.observed[3] and not seen.observed[4], (degrees, seen.observed)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), step=st.tuples(*[st.floats(-20.0, 20.0)] * 3))
def test_from_every_face_everything_is_seen_and_a_bias_step_is_fitted_as_itself(seed, step):
    rng = np.random.default_rng(seed)
    faces = np.concatenate([np.eye(3), -np.eye(3)])
    extra = rng.normal(size=(4, 3))
    seen, jacobian = seen_from(np.concatenate([faces, extra / np.linalg.norm(extra, axis=1)[:, None]]))
    assert seen.observed.all() and seen.groups == ()
    change = np.concatenate([np.array(step) * MG, np.zeros(3)])
    fitted = seen.estimator(jacobian, np.ones(len(jacobian))) @ (jacobian @ change)
    np.testing.assert_allclose(fitted, change, atol=1e-9)
