"""The fast paths of fit() give what the plain computations give: the stacked residuals and
Jacobian, the stacked Gauss-Newton, the Cholesky seed, the leverages, sigma and condition number
from one normal matrix, and the Calibration's float validation. Each is checked against a plain,
independent numpy computation, to rounding."""
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from accel_calibration import Calibration, CalibrationError, fit
from accel_calibration.core.calibration import _scaled_determinant
from accel_calibration.core.fit_outliers import critical_ratio as _critical_ratio
from accel_calibration.core.gauss_newton import gauss_newton, gauss_newton_stacked
from accel_calibration.core.models import SphereModel, _ellipsoid_coefficients, seed_sphere

G = 9.80665
FACES = np.vstack([np.eye(3), -np.eye(3)])


def poses(seed, n=24, noise=0.002, counts=False, model="sphere9"):
    """A MEMS part the model describes (diagonal M for six): small residuals, as the optimum tests need."""
    rng = np.random.default_rng(seed)
    directions = Rotation.random(n, random_state=rng).apply([0.0, 0.0, 1.0])
    directions[:6] = FACES
    matrix = np.eye(3) + np.tril(rng.normal(0, 0.01, (3, 3)))
    if model == "six":
        matrix = np.diag(np.diag(matrix))
    bias = rng.normal(0, 0.3, 3)
    raw = (G * directions) @ np.linalg.inv(matrix).T + bias + rng.normal(0, noise, (n, 3))
    return 32768 + 400 * raw if counts else raw


def plain_residual_and_jacobian(model, p, accel, gravity):
    """|M (a - b)| - g and its Jacobian, written out entry by entry."""
    bias, matrix = model.unpack(p)
    centred = accel - bias
    corrected = centred @ matrix.T
    norm = np.linalg.norm(corrected, axis=1)
    jac = np.zeros((len(accel), model.size))
    jac[:, :3] = -(corrected @ matrix) / norm[:, None]
    for k, (i, j) in enumerate(model.entries):
        jac[:, 3 + k] = corrected[:, i] * centred[:, j] / norm
    return norm - gravity, jac


seeds = st.integers(0, 2**32 - 1)


@settings(max_examples=60, deadline=None)
@given(seed=seeds, name=st.sampled_from(["six", "sphere9"]), n=st.integers(1, 40))
def test_stacked_residuals_and_jacobian_are_the_plain_ones(seed, name, n):
    rng = np.random.default_rng(seed)
    model = SphereModel(name)
    accel = rng.normal(0, 10, (n, 3))
    p = np.concatenate([rng.normal(0, 1, 3), rng.normal(1, 0.05, model.size - 3)])
    r, jac = plain_residual_and_jacobian(model, p, accel, G)
    stacked = model.stacked(p, np.ascontiguousarray(accel.T), G)
    assert stacked.shape == (model.size + 1, n)
    assert_allclose(stacked[-1], r, rtol=0, atol=1e-12 * G)
    assert_allclose(stacked[:-1].T, jac, rtol=1e-12, atol=1e-14)
    r2, jac2 = model.residual_and_jacobian(p, accel, G)
    assert_allclose(r2, r, rtol=0, atol=1e-12 * G)
    assert_allclose(jac2, jac, rtol=1e-12, atol=1e-14)


@settings(max_examples=25, deadline=None)
@given(seed=seeds, name=st.sampled_from(["six", "sphere9"]), n=st.integers(12, 40), counts=st.booleans())
@example(seed=911253579, name="sphere9", n=17, counts=False)  # 2.0e-9 apart: the optimum's own precision
def test_stacked_gauss_newton_lands_on_scipys_optimum(seed, name, n, counts):
    accel = poses(seed, n, counts=counts, model=name)
    model = SphereModel(name)
    x0 = model.project(*seed_sphere(accel, G))
    accel_t = np.ascontiguousarray(accel.T)
    ours = gauss_newton_stacked(lambda p: model.stacked(p, accel_t, G), x0)
    generic = gauss_newton(lambda p: plain_residual_and_jacobian(model, p, accel, G), x0)

    def fun(p):
        return plain_residual_and_jacobian(model, p, accel, G)

    reference = least_squares(lambda p: fun(p)[0], x0, jac=lambda p: fun(p)[1], ftol=1e-15, xtol=1e-15, gtol=1e-15)
    assert ours.success and generic.success
    scale = np.abs(reference.x)
    # Where the cost is this flat, a minimum's position is defined to ~sqrt(eps * cond) (~1e-8 of the
    # parameters' scale, the cost to 1e-16): two solvers stopping at it differ by up to that.
    assert_allclose(ours.x, reference.x, rtol=0, atol=1e-8 * scale.max())
    assert_allclose(generic.x, ours.x, rtol=0, atol=1e-8 * scale.max())
    assert ours.cost == pytest.approx(reference.cost, rel=1e-8, abs=1e-20)
    # The normal matrix the solver hands on is J^T J at the point it returns.
    jac = plain_residual_and_jacobian(model, ours.x, accel, G)[1]
    assert ours.normal is not None
    assert_allclose(ours.normal, jac.T @ jac, rtol=1e-10, atol=1e-12 * np.abs(jac.T @ jac).max())


@settings(max_examples=60, deadline=None)
@given(seed=seeds, n=st.integers(6, 60), counts=st.booleans())
def test_cholesky_seed_is_the_svd_least_squares_solution(seed, n, counts):
    accel = poses(seed, max(n, 6), counts=counts)
    centred = accel - accel.mean(axis=0)
    x = centred / np.abs(centred).max()
    design = np.hstack([x**2, x])
    svd = np.linalg.lstsq(design, np.ones(len(x)), rcond=None)[0]
    assert_allclose(_ellipsoid_coefficients(x), svd, rtol=1e-11, atol=1e-11 * np.abs(svd).max())


def test_rank_deficient_seed_design_takes_the_svd_path_unchanged():
    """Poses in one plane: [x^2, x] is singular, and the minimum-norm SVD answer is what comes back."""
    angles = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    x = np.column_stack([np.cos(angles), np.sin(angles), np.zeros(12)])
    svd = np.linalg.lstsq(np.hstack([x**2, x]), np.ones(12), rcond=None)[0]
    assert np.array_equal(np.array(_ellipsoid_coefficients(x)), svd)


@settings(max_examples=60, deadline=None)
@given(seed=seeds, n=st.integers(12, 60), counts=st.booleans())
def test_cross_axis_seed_is_the_general_ellipsoid_and_starts_at_the_optimum(seed, n, counts):
    """sphere9's seed: the general quadric through the poses (plain SVD least squares, centre and shape by
    numpy), written as b and a lower-triangular M with |M (a - b)| = g on it; within noise of the optimum,
    so Gauss-Newton takes two iterations (the axis-aligned seed took four)."""
    accel = poses(seed, n, counts=counts)
    bias, matrix = seed_sphere(accel, G, cross_axis=True)
    centre = accel.mean(axis=0)
    x = (accel - centre) / np.abs(accel - centre).max()
    design = np.column_stack([x**2, x[:, 0] * x[:, 1], x[:, 0] * x[:, 2], x[:, 1] * x[:, 2], x])
    c = np.linalg.lstsq(design, np.ones(n), rcond=None)[0]
    quadric = np.array([[c[0], c[3] / 2, c[4] / 2], [c[3] / 2, c[1], c[5] / 2], [c[4] / 2, c[5] / 2, c[2]]])
    offset = -0.5 * np.linalg.solve(quadric, c[6:])
    spread = np.abs(accel - centre).max()
    assert_allclose(bias, centre + offset * spread, rtol=1e-9, atol=1e-9 * np.abs(bias).max())
    shape = G**2 * quadric / (1 + offset @ quadric @ offset) / spread**2
    assert_allclose(matrix.T @ matrix, shape, rtol=1e-8, atol=1e-9 * np.abs(shape).max())
    assert np.array_equal(np.tril(matrix), matrix) and np.all(np.diag(matrix) > 0)
    result = fit(accel)
    assert result.success and result.iterations <= 2, (result.iterations, result.message)


@pytest.mark.parametrize("layout", ["faces", "plane"])
def test_cross_axis_seed_gives_way_to_the_axis_aligned_one_where_the_poses_leave_it_loose(layout):
    """Poses only at the six faces say nothing of the cross terms, poses in one plane nothing of the third
    axis: the axis-aligned seed, exactly as without cross_axis, and the six faces still fit."""
    rng = np.random.default_rng(4)
    if layout == "faces":
        directions = np.vstack([FACES, FACES])
    else:
        angles = np.linspace(0, 2 * np.pi, 12, endpoint=False)
        directions = np.column_stack([np.cos(angles), np.sin(angles), np.zeros(12)])
    accel = G * directions @ np.diag([1.01, 0.99, 1.02]) + [0.1, -0.2, 0.3] + rng.normal(0, 0.002, (len(directions), 3))
    for got, axis_aligned in zip(seed_sphere(accel, G, cross_axis=True), seed_sphere(accel, G)):
        assert np.array_equal(got, axis_aligned)
    if layout == "faces":
        assert fit(accel, model="six").success


@pytest.mark.parametrize("seed", range(8))
def test_fit_sigma_condition_and_leverage_equal_their_definitions(seed):
    accel = poses(seed, 24)
    result = fit(accel)
    assert result.success, result.message
    model = SphereModel("sphere9")
    c = result.calibration
    p = model.pack(c.bias, c.matrix)
    r, jac = plain_residual_and_jacobian(model, p, accel, G)
    normal = jac.T @ jac
    covariance = np.linalg.inv(normal) * (r @ r) / (len(accel) - model.size)
    stds = np.sqrt(np.diag(covariance))
    assert_allclose(result.sigma.bias, stds[:3], rtol=1e-8)
    assert_allclose([result.sigma.matrix[i, j] for i, j in model.entries], stds[3:], rtol=1e-8)
    assert_allclose(result.residuals_mg, r / (G * 1e-3), rtol=0, atol=1e-9)
    scaled = normal / np.sqrt(np.outer(np.diag(normal), np.diag(normal)))
    eigenvalues = np.linalg.eigvalsh(scaled)
    assert result.condition_number == pytest.approx(eigenvalues[-1] / eigenvalues[0], rel=1e-8)
    leverage = np.diag(jac @ np.linalg.inv(normal) @ jac.T)
    assert_allclose(result.leverage, leverage, rtol=1e-8, atol=1e-12)
    assert result.leverage.sum() == pytest.approx(model.size, rel=1e-9)  # the trace of a projection
    assert_allclose(result.uncertainty.normal, normal, rtol=1e-10, atol=1e-12 * np.abs(normal).max())


finite = st.floats(-1e6, 1e6, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(st.lists(finite, min_size=9, max_size=9))
def test_scaled_determinant_is_numpys(values):
    matrix = np.array(values).reshape(3, 3)
    rows = np.abs(matrix).max(axis=1)
    if not np.all(rows > 0):
        assert _scaled_determinant(matrix) == 0.0
        return
    assert _scaled_determinant(matrix) == pytest.approx(np.linalg.det(matrix / rows[:, None]), abs=1e-12)


@pytest.mark.parametrize("field, value, says", [
    ("bias", np.array([0.0, np.nan, 0.0]), "bias must be finite"),
    ("bias", [0.0, 0.0], "bias must have shape (3,)"),
    ("bias", "abc", "bias must be numbers"),
    ("matrix", np.array([[1.0, 0, 0], [0, np.inf, 0], [0, 0, 1]]), "matrix must be finite"),
    ("matrix", np.diag([1.0, 1.0, 0.0]), "matrix is singular"),
    ("matrix", np.array([[1.0, 2, 3], [2, 4, 6], [0, 0, 1]]), "matrix is singular"),
    ("matrix_sigma", np.full((3, 3), -np.inf), "matrix_sigma must be finite"),
    ("bias_sigma", np.ones(4), "bias_sigma must have shape (3,)"),
])
def test_calibration_validation_refuses_as_before(field, value, says):
    arguments = {"bias": np.zeros(3), "matrix": np.eye(3), field: value}
    with pytest.raises(CalibrationError, match=None) as error:
        Calibration(**arguments)
    assert says in str(error.value)


def test_calibration_holds_read_only_copies_and_an_iso_utc_stamp():
    bias, matrix = np.array([0.1, 0.2, 0.3]), np.eye(3) * 1.01
    c = Calibration(bias=bias, matrix=matrix)
    bias[0] = 5.0
    assert c.bias[0] == 0.1 and not c.bias.flags.writeable and not c.matrix.flags.writeable
    assert c.created.endswith("+00:00") and len(c.created) == len("2026-11-22T21:41:22+00:00")
    import datetime
    stamp = datetime.datetime.fromisoformat(c.created)
    assert abs((datetime.datetime.now(datetime.UTC) - stamp).total_seconds()) < 3600


def test_fit_imports_scipy_stats_only_when_an_outlier_is_judged():
    # What every command loads (the CLI, replay, the session) must not pull scipy.stats in.
    code = ("import sys, accel_calibration.core.fit, accel_calibration.core.temperature_models, "
            "accel_calibration.core.session, accel_calibration.cli.main, accel_calibration.bag.replay; "
            "print('scipy.stats' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
    # And the quantile the outlier test uses is still scipy's: F(1, 10) at 5 sigma two-sided.
    from scipy.special import erfc
    from scipy.stats import f
    assert _critical_ratio(5.0, 1, 10) == pytest.approx(f.ppf(1 - erfc(5 / np.sqrt(2)), 1, 10), rel=1e-12)
    # The pose store's agreement bound, written out, is scipy's chi-square quantile.
    from scipy.stats import chi2

    from accel_calibration.core.pose_store import AGREEMENT_CHI2
    assert AGREEMENT_CHI2 == float(chi2.ppf(0.999, 3))


def test_calibration_from_fit_equals_the_full_constructor_and_refuses_alike():
    rng = np.random.default_rng(4)
    arrays = dict(bias=rng.normal(0, 0.3, 3), matrix=np.eye(3) + np.tril(rng.normal(0, 0.01, (3, 3))),
                  bias_sigma=np.abs(rng.normal(0, 1e-3, 3)), matrix_sigma=np.tril(np.abs(rng.normal(0, 1e-4, (3, 3)))))
    others = dict(model="sphere9", gravity=9.81, frame_id="imu", reference_temperature_degc=25.0)
    fast = Calibration.from_fit(**arrays, **others)
    full = Calibration(**arrays, **others, created=fast.created)
    assert fast == full and fast.quality is None and fast.temperature is None and fast.sensor_id == ""
    for name in arrays:
        held = getattr(fast, name)
        assert not held.flags.writeable and not np.shares_memory(held, arrays[name])
    with pytest.raises(CalibrationError, match="matrix is singular"):
        Calibration.from_fit(**{**arrays, "matrix": np.array([[1.0, 0, 0], [2.0, 1e-13, 0], [0, 0, 1]])}, **others)
    with pytest.raises(CalibrationError, match="unknown model"):
        Calibration.from_fit(**arrays, **{**others, "model": "sphere12"})
    with pytest.raises(CalibrationError, match="gravity must be"):
        Calibration.from_fit(**arrays, **{**others, "gravity": -1.0})
    # Anything from_fit does not check itself goes through the full validation.
    with pytest.raises(CalibrationError, match="quadratic must be finite"):
        Calibration.from_fit(**arrays, **others, quadratic=np.array([0.0, np.nan, 0.0]))
