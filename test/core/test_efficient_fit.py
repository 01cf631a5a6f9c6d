"""Poses weighted by the inverse variance of their means, w_i = 1 / (s_i^2 + tau^2):
equal noise gives today's fit exactly, tau makes chi^2/dof = 1, the weighted fit is closer to the truth
when poses differ in length, and --poses-out tables carry each pose's sigma back into `fit`."""
import csv
import io

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from accel_calibration.cli.main import main
from accel_calibration.core.fit import OutlierOptions, fit
from accel_calibration.core.models import SphereModel
from accel_calibration.core.pose import Pose
from accel_calibration.core.pose_map import PoseStatus
from accel_calibration.core.pose_weights import extra_variance, pose_weights
from accel_calibration.io.pose_table import read_table
from accel_calibration.io.poses_out import poses_table_text

G = 9.80665
MG = G * 1e-3
NO_OUTLIERS = OutlierOptions(threshold_mg=0.0)


def session(rng, n=24):
    """A random geometry: directions, a sphere9 truth (b, M) and the clean raw pose means."""
    directions = Rotation.random(n, random_state=rng).apply([0.0, 0.0, 1.0])
    matrix = np.eye(3) + np.tril(rng.normal(0.0, 5e-3, (3, 3)))
    bias = rng.normal(0.0, 50 * MG, 3)
    return directions, bias, matrix, (G * directions) @ np.linalg.inv(matrix).T + bias


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), model=st.sampled_from(["six", "sphere9", "reference12", "reference15"]),
       sigma_mg=st.floats(0.01, 2.0))
def test_equal_pose_noise_gives_todays_fit_exactly(seed, model, sigma_mg):
    rng = np.random.default_rng(seed)
    directions, _, _, clean = session(rng)
    noisy = clean + rng.normal(0.0, sigma_mg * MG, clean.shape)
    reference = directions if model.startswith("reference") else None
    today = fit(noisy, model=model, reference=reference)
    weighted = fit(noisy, model=model, reference=reference, pose_sigma_mps2=np.full(len(noisy), sigma_mg * MG))
    assert weighted.pose_extra_sigma is None
    assert weighted.calibration.replace(created="") == today.calibration.replace(created="")
    np.testing.assert_array_equal(weighted.residuals_mg, today.residuals_mg)


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), dof=st.integers(1, 60), scatter=st.floats(0.1, 10.0))
def test_extra_variance_makes_chi2_equal_its_dof(seed, dof, scatter):
    rng = np.random.default_rng(seed)
    variance = rng.uniform(0.1, 3.0, dof + 9) ** 2
    squared = scatter * variance * rng.chisquare(1, len(variance))
    tau2 = extra_variance(squared, variance, dof)
    chi2 = float(np.sum(squared / (variance + tau2)))
    if tau2 > 0:
        assert abs(chi2 - dof) <= 1e-9 * dof
    else:
        assert float(np.sum(squared / variance)) <= dof


def test_weighted_sphere_fit_has_chi2_per_dof_one_and_reports_tau():
    """With a common extra error the fit finds it, and its weighted residuals have chi^2/dof = 1. As on the
    imu_tk Xsens recording: 11-54 ug of sample noise per pose mean, 110 ug of extra error; 40 poses."""
    rng = np.random.default_rng(4)
    taus = []
    for _ in range(30):
        _, _, _, clean = session(rng, n=40)
        sigma = rng.uniform(0.011, 0.054, len(clean)) * MG
        noisy = clean + rng.normal(0.0, 1.0, clean.shape) * np.sqrt(sigma**2 + (0.110 * MG) ** 2)[:, None]
        result = fit(noisy, model="sphere9", pose_sigma_mps2=sigma, outlier_options=NO_OUTLIERS)
        assert result.success and result.pose_extra_sigma is not None and result.pose_extra_sigma > 0
        gain = np.mean(np.linalg.norm(result.calibration.matrix, axis=1))
        chi2 = np.sum((result.residuals_mg * MG / gain) ** 2 / (sigma**2 + result.pose_extra_sigma**2))
        assert abs(chi2 / (len(noisy) - 9) - 1.0) < 1e-3
        taus.append(result.pose_extra_sigma / MG)
    assert abs(np.mean(taus) - 0.110) < 0.01, np.mean(taus)  # mg; one fit's tau scatters ~15 %
    assert "common extra error of 0." in result.summary()
    # Weights are 1 / (s_i^2 + tau^2), scaled to mean 1.
    expected = 1 / (sigma**2 + result.pose_extra_sigma**2)
    np.testing.assert_allclose(pose_weights(sigma**2, result.pose_extra_sigma**2), expected / expected.mean())


def _monte_carlo(model, draws=150, seed=8):
    """Summed mean-square error of the parameters over draws, unweighted and weighted, for one geometry of
    24 poses of 1-10 s (pose noise proportional to 1 / sqrt(length))."""
    rng = np.random.default_rng(seed)
    directions, bias, matrix, clean = session(rng)
    sigma = 0.3 * MG / np.sqrt(rng.uniform(1.0, 10.0, len(clean)))
    truth = np.concatenate([bias, matrix.ravel()])
    reference = directions if model.startswith("reference") else None
    squared = {"unweighted": 0.0, "weighted": 0.0}
    for _ in range(draws):
        noisy = clean + rng.normal(0.0, 1.0, clean.shape) * sigma[:, None]
        for name, pose_sigma in (("unweighted", None), ("weighted", sigma)):
            c = fit(noisy, model=model, reference=reference, pose_sigma_mps2=pose_sigma,
                    outlier_options=NO_OUTLIERS).calibration
            if model == "sphere9":  # compare in sphere9's frame (the truth is lower-triangular already)
                c_bias, c_matrix = SphereModel("sphere9").unpack(SphereModel("sphere9").project(c.bias, c.matrix))
            else:
                c_bias, c_matrix = c.bias, c.matrix
            error = (np.concatenate([c_bias, c_matrix.ravel()]) - truth) / np.concatenate([[MG] * 3, [1e-3] * 9])
            squared[name] += float(error @ error)
    return squared


def test_weighting_brings_the_fit_closer_to_the_truth():
    """The direction of the improvement, on a small Monte Carlo (bench/bench_efficiency.py measures it
    against the Cramér-Rao bound): the weighted fit's mean-square error is below the unweighted one's."""
    for model in ("sphere9", "reference12"):
        squared = _monte_carlo(model)
        assert squared["weighted"] < 0.9 * squared["unweighted"], (model, squared)


def test_poses_out_carries_sigma_mg_and_fit_reads_it_back(tmp_path, capsys):
    rng = np.random.default_rng(9)
    _, _, _, clean = session(rng)
    samples = rng.integers(100, 1000, len(clean))
    spread = (3 * MG) ** 2  # per axis, of one sample
    noisy = clean + rng.normal(0.0, 1.0, clean.shape) * np.sqrt(spread / samples)[:, None]
    poses = [Pose(a, np.eye(3) * spread, int(n), 0, int(n) * 10_000_000) for a, n in zip(noisy, samples)]
    text = poses_table_text(poses, [PoseStatus.USED] * len(poses))
    rows = list(csv.DictReader(io.StringIO(text)))
    np.testing.assert_allclose([float(r["sigma_mg"]) for r in rows], 3.0 / np.sqrt(samples), rtol=1e-12)
    (tmp_path / "poses.csv").write_text(text)
    table = read_table(tmp_path / "poses.csv")
    np.testing.assert_allclose(table.pose_sigma_mps2, 3 * MG / np.sqrt(samples), rtol=1e-12)
    assert main(["fit", str(tmp_path / "poses.csv"), "-o", str(tmp_path / "cal.yaml")]) == 0
    assert "poses weighted by their own noise" in capsys.readouterr().out
    direct = fit(poses)  # Pose objects: the same sigmas from their covariance and sample count
    assert direct.pose_extra_sigma is not None


def test_imu_tk_xsens_recording_weights_come_out_nearly_equal(shared):
    """The imu_tk Xsens MTi recording (raw counts, local g 9.81744): its 39 poses scatter ~3x beyond their
    sample noise (11-54 ug per pose mean); tau comes out near 110 ug, so the weights are nearly equal and
    the fit stays today's. Weights 1 / s_i^2 from the sample count alone would make every parameter's
    variance 3-43 % worse (sandwich covariance with the noise s_i^2 + tau^2 the poses show)."""
    import gzip

    from accel_calibration.core.fit import pose_mean_sigma
    from accel_calibration.core.fit_outliers import sphere_rows as _sphere_rows
    from accel_calibration.core.stream.detector import StaticDetector

    accel = np.loadtxt(gzip.open(shared("real/imu_tk/xsens_acc.txt.gz")))
    gyro = np.loadtxt(gzip.open(shared("real/imu_tk/xsens_gyro.txt.gz")))
    poses = StaticDetector().process((accel[:, 0] * 1e9).astype(np.int64), accel[:, 1:], gyro[:, 1:])
    gravity = 9.81744
    means = np.array([p.accel_mps2 for p in poses])
    sigma = pose_mean_sigma(poses)  # counts
    plain, weighted = fit(means, gravity=gravity), fit(poses, gravity=gravity)
    assert len(poses) == 39 and plain.success and weighted.success and weighted.outliers == ()
    counts_per_ug = 1e-6 * G / np.sqrt(np.sum(plain.calibration.matrix**2) / 3)
    assert 10 < sigma.min() / counts_per_ug and sigma.max() / counts_per_ug < 55
    tau = weighted.pose_extra_sigma
    assert 95 < tau / counts_per_ug < 125, tau / counts_per_ug
    model = SphereModel("sphere9")
    step = (model.pack(weighted.calibration.bias, weighted.calibration.matrix)
            - model.pack(plain.calibration.bias, plain.calibration.matrix))
    assert np.all(np.abs(step) < 0.1 * model.pack(plain.sigma.bias, plain.sigma.matrix))
    rows = _sphere_rows(plain.calibration, means, None)
    variance = sigma**2 + tau**2

    def covariance(weights):
        inverse = np.linalg.inv(rows.T @ (rows * weights[:, None]))
        return np.diag(inverse @ (rows.T @ (rows * (weights**2 * variance)[:, None])) @ inverse)

    today = covariance(np.ones(len(poses)))
    sample_count_only = covariance(1 / sigma**2) / today
    assert sample_count_only.min() > 1.02 and sample_count_only.max() > 1.4, sample_count_only
    assert np.all(covariance(1 / variance) / today < 1.001)
    assert (1 / variance).max() / (1 / variance).min() < 1.3
