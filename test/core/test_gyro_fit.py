"""Gyro scale and misalignment from the motions between still poses: the integration and its
Jacobian against independent references, simulated hand-turned sessions against their truth (and sigma
against Monte Carlo), refusals with what to do, and the imu_tk Xsens recording."""
import gzip
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from accel_calibration import Calibration, CalibrationError, fit
from accel_calibration.core.gyro_fit import GyroFitOptions, Motion, fit_gyro, motions_between
from accel_calibration.core.gyro_gates import GyroGates
from accel_calibration.core.gyro_scoring import motion_residuals_mrad
from accel_calibration.core.refusal import GyroGate, MotionProblem
from accel_calibration.core.rotation_integration import IntervalSet, prefix_product, quaternion_exp
from accel_calibration.core.session import CalibrationSession
from accel_calibration.core.settings import Settings
from msg_tools.synthetic_motion import GyroTruth, simulate_session

from helpers.gyro_sessions import poses_and_motions
from helpers.imu_tk_files import in_our_units

OFF_DIAGONAL = ~np.eye(3, dtype=bool)


def errors(result, truth):
    """Scale error (relative, per axis) and misalignment error (rad, off-diagonal entries) against the truth."""
    difference = result.matrix - truth
    gains = np.linalg.norm(truth, axis=1)
    return np.diag(difference) / gains, difference[OFF_DIAGONAL] / gains[np.nonzero(OFF_DIAGONAL)[0]]


def simulated_fit(seed, poses=18, rate_hz=200.0, options=None, **session):
    simulated = simulate_session(np.random.default_rng(seed), poses=poses, rate_hz=rate_hz, **session)
    pose_list, motions = poses_and_motions(simulated)
    accel = fit(pose_list).calibration
    result = fit_gyro(pose_list, motions, accel, gyro_noise_radps=simulated.gyro_noise_radps, options=options)
    return simulated, result


# ------------------------------------------------------------------ integration and Jacobian
def _sequential(stamps_ns, rates, matrix, substeps=64):
    """The rotation of a rate linear between samples, integrated by many small constant-rate steps."""
    rotation = Rotation.identity()
    for j in range(len(stamps_ns) - 1):
        dt = (stamps_ns[j + 1] - stamps_ns[j]) * 1e-9
        for k in range(substeps):
            share = (k + 0.5) / substeps
            rate = matrix @ ((1 - share) * rates[j] + share * rates[j + 1])
            rotation = rotation * Rotation.from_rotvec(rate * dt / substeps)
    return rotation.as_matrix()


def test_integration_of_a_turning_rate_is_third_order_exact():
    """A hand-like rate whose axis turns (coning): the integration on the stamps, with its coning term,
    agrees with a 64-substep integration of the same linearly interpolated rate to 1e-7 rad at 100 Hz,
    where leaving the coning term out is off by ~1e-4 rad."""
    rng = np.random.default_rng(3)
    stamps = np.cumsum(rng.integers(9_500_000, 10_500_000, 200)).astype(np.int64)
    t = (stamps - stamps[0]) * 1e-9
    rates = np.stack([3 * np.sin(2.1 * t), 2 * np.cos(1.3 * t), 1.5 * np.sin(0.7 * t + 1)], axis=1)
    matrix = np.eye(3) + rng.normal(0, 0.02, (3, 3))
    intervals = IntervalSet([stamps], [rates], [np.linspace(0, 1, len(stamps))])
    ours = intervals.rotations(matrix, np.zeros(3))[0]
    reference = _sequential(stamps, rates, matrix)
    assert np.abs(Rotation.from_matrix(ours.T @ reference).as_rotvec()).max() < 1e-7
    plain = np.eye(3)
    for j in range(len(stamps) - 1):
        mean = matrix @ (0.5 * (rates[j] + rates[j + 1]))
        plain = plain @ Rotation.from_rotvec(mean * (stamps[j + 1] - stamps[j]) * 1e-9).as_matrix()
    assert np.abs(Rotation.from_matrix(plain.T @ reference).as_rotvec()).max() > 1e-5


def test_jacobian_is_exact():
    """d phi / d (M_g, bias change) against central differences of the integrated rotation."""
    rng = np.random.default_rng(1)
    stamps, rates = [], []
    for n in (40, 300, 7):
        stamps.append(np.cumsum(rng.integers(900_000, 1_100_000, n)).astype(np.int64))
        rates.append(rng.normal(0, 2, (n, 3)))
    intervals = IntervalSet(stamps, rates, [np.linspace(0, 1, len(t)) for t in stamps])
    matrix, bias = np.eye(3) + rng.normal(0, 0.02, (3, 3)), rng.normal(0, 0.01, 3)
    rotations, d_phi, _ = intervals.rotations_and_derivatives(matrix, bias, with_bias=True)
    x, step = np.concatenate([matrix.ravel(), bias]), 1e-6
    for i in range(12):
        up, down = x.copy(), x.copy()
        up[i] += step
        down[i] -= step
        plus = intervals.rotations(up[:9].reshape(3, 3), up[9:])
        minus = intervals.rotations(down[:9].reshape(3, 3), down[9:])
        change = np.einsum("kba,kbc->kac", rotations, (plus - minus) / (2 * step))  # R^T dR = [d phi]x
        numeric = np.stack([change[:, 2, 1], change[:, 0, 2], change[:, 1, 0]], axis=1)
        assert_allclose(d_phi[:, :, i], numeric, atol=1e-8 * max(1.0, np.abs(numeric).max()))


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 700), st.integers(0, 2**31))
def test_blocked_scan_equals_the_sequential_product(count, seed):
    quaternions = quaternion_exp(np.random.default_rng(seed).normal(0, 0.5, (count, 3)))
    running = prefix_product(quaternions)
    rotation = Rotation.identity()
    for i in (0, count // 2, count - 1):
        rotation = Rotation.from_quat(quaternions[: i + 1][:, [1, 2, 3, 0]][0])
        for q in quaternions[1: i + 1]:
            rotation = rotation * Rotation.from_quat(q[[1, 2, 3, 0]])
        assert_allclose(Rotation.from_quat(running[i][[1, 2, 3, 0]]).as_matrix(), rotation.as_matrix(), atol=1e-12)


# ------------------------------------------------------------------ simulated sessions
@pytest.mark.parametrize("seed, poses, rate_hz", [(11, 18, 200.0), (12, 24, 1000.0), (13, 20, 400.0)])
def test_simulated_session_recovers_scale_and_misalignment(seed, poses, rate_hz):
    """1-3 % scale, 2-20 mrad misalignment, MPU-6050 noise, drifting bias, earth rate: the scale within
    0.05 %, the misalignment within 0.3 mrad, from 18-24 poses."""
    simulated, result = simulated_fit(seed, poses, rate_hz)
    assert result.success, result.message
    assert result.motions_used == poses - 1 and not result.refused
    scale, misalignment = errors(result, simulated.gyro.matrix)
    assert np.abs(scale).max() < 5e-4, scale
    assert np.abs(misalignment).max() < 0.3e-3, misalignment
    assert result.residual_rms_mrad < 1.0 < 20 < result.residual_rms_before_mrad
    assert GyroGates().check(result) is None


def test_twelve_poses_are_within_their_sigma():
    """12 poses (11 motions) pin the misalignment to ~0.2 mrad (1 sigma): within 3 sigma, and the scale
    within 0.05 %; the 0.3 mrad target needs about 18 poses (docs/gyro.md)."""
    simulated, result = simulated_fit(14, poses=12)
    assert result.success, result.message
    scale, misalignment = errors(result, simulated.gyro.matrix)
    assert np.abs(scale).max() < 5e-4
    sigma = result.matrix_sigma / np.linalg.norm(simulated.gyro.matrix, axis=1)[:, None]
    assert np.all(np.abs(misalignment) < 3 * sigma[OFF_DIAGONAL])
    assert result.misalignment_sigma_mrad().max() < 0.3


def test_noise_free_session_is_recovered_to_the_integration_error():
    """Without noise the fit is exact to the integration's third-order error at 200 Hz (a few urad); the
    earth's rate, which the bias interpolated between poses follows only in part, adds ~0.05 mrad."""
    truth = GyroTruth.random(np.random.default_rng(5), noise_density=1e-12, bias_walk=0.0)
    for earth_rate, bound in ((0.0, 1e-5), (7.292115e-5, 1e-4)):
        simulated, result = simulated_fit(5, gyro=truth, accel_noise_density=1e-9, earth_rate_radps=earth_rate)
        scale, misalignment = errors(result, truth.matrix)
        assert np.abs(scale).max() < bound and np.abs(misalignment).max() < bound, (earth_rate, scale, misalignment)


def test_sigma_is_honest():
    """Monte Carlo: over 30 sessions (12-24 poses, 200 Hz), at least 95 % of the fitted entries of M_g lie
    within 2 sigma of the truth, and sigma is not grossly pessimistic either (rms of error / sigma > 0.7)."""
    z = []
    for seed in range(30):
        rng = np.random.default_rng(100 + seed)
        simulated, result = simulated_fit(100 + seed, poses=int(rng.integers(12, 25)))
        z.extend(((result.matrix - simulated.gyro.matrix) / result.matrix_sigma).ravel())
    z = np.array(z)
    assert np.mean(np.abs(z) < 2) >= 0.95, np.mean(np.abs(z) < 2)
    assert 0.7 < np.sqrt(np.mean(z**2)) < 1.3


def test_a_fitted_residual_bias_is_within_its_sigma():
    simulated, result = simulated_fit(21, options=GyroFitOptions(fit_bias=True))
    assert result.success and result.bias_sigma_radps is not None
    mean_true_bias = simulated.gyro.bias_radps  # the drift over the session is ~1e-5 rad/s
    assert np.all(np.abs(result.bias_radps - mean_true_bias) < 4 * result.bias_sigma_radps + 5e-5)


def test_turns_about_two_axes_only_ask_for_the_third():
    """Motions that never turn about the sensor's z: the fit says which axis to turn about."""
    simulated = simulate_session(np.random.default_rng(31), poses=16, turn_axes="xy")
    poses, motions = poses_and_motions(simulated)
    result = fit_gyro(poses, motions, fit(poses).calibration, gyro_noise_radps=simulated.gyro_noise_radps)
    # z is seen only through the misalignment (raw z reads ~1 % of the turns): its column is loose.
    assert result.scale_sigma_ppm()[2] > 3 * result.scale_sigma_ppm()[:2].max()
    refusal = GyroGates(max_scale_sigma_ppm=200.0).check(result)
    assert refusal.gate is GyroGate.SIGMA
    assert str(refusal).startswith("gyro: gate sigma: scale z sigma")
    assert str(refusal).endswith("motions turned about x and y only; turn about z between poses (not about the "
                                 "vertical)")
    # Turns about x alone leave y and z undetermined: the fit itself refuses. (The poses lie on one circle,
    # too few for the accelerometer's own fit: its truth stands in.)
    simulated = simulate_session(np.random.default_rng(32), poses=16, turn_axes="x")
    poses, motions = poses_and_motions(simulated)
    accel = Calibration(bias=simulated.accel_bias_mps2, matrix=simulated.accel_matrix)
    result = fit_gyro(poses, motions, accel, gyro_noise_radps=simulated.gyro_noise_radps)
    assert not result.success
    assert result.message.startswith("motions turned about x only; turn about y and z between poses")
    assert GyroGates().check(result).gate is GyroGate.FIT
    assert str(GyroGates().check(result)).startswith("gyro: gate fit: motions turned about x only")


# ------------------------------------------------------------------ refusals
def test_motions_that_cannot_be_used_are_counted_with_their_reason():
    simulated = simulate_session(np.random.default_rng(41), poses=14)
    poses, motions = poses_and_motions(simulated)
    motions = list(motions)
    motions[1] = None  # the buffer overflowed
    motions[2] = replace(motions[2], paused=True)
    keep = np.ones(len(motions[3].stamps_ns), bool)
    keep[100:110] = False  # 10 samples lost
    motions[3] = Motion(motions[3].stamps_ns[keep], motions[3].gyro_radps[keep])
    spiked = motions[4].gyro_radps.copy()
    spiked[50, 0] = 40.0
    motions[4] = Motion(motions[4].stamps_ns, spiked)
    motions[5] = Motion(motions[5].stamps_ns[40:], motions[5].gyro_radps[40:])  # starts late
    result = fit_gyro(poses, motions, fit(poses).calibration, gyro_noise_radps=simulated.gyro_noise_radps,
                      options=GyroFitOptions(max_motion_s=30.0))
    assert result.refused_counts() == {MotionProblem.NOT_RECORDED: 1, MotionProblem.PAUSED: 1, MotionProblem.GAP: 1,
                                       MotionProblem.SATURATED: 1, MotionProblem.SPAN: 1}
    assert [r.index for r in result.refused] == [1, 2, 3, 4, 5]
    assert result.motions_used == 8
    assert "gap of" in result.refused[2].reason and "gyro_range_radps" in result.refused[3].reason
    short = fit_gyro(poses, motions, fit(poses).calibration, options=GyroFitOptions(max_motion_s=1.0))
    assert not short.success and short.refused_counts()[MotionProblem.LONG] >= 1
    assert "usable motions, need at least 5" in short.message
    refusal = GyroGates().check(short)
    assert refusal.gate is GyroGate.MOTIONS
    assert str(refusal).startswith("gyro: gate motions:") and "long" in str(refusal)


def test_motions_between_cut_a_recording_at_the_poses():
    simulated = simulate_session(np.random.default_rng(42), poses=12)
    poses, motions = poses_and_motions(simulated)
    collecting = np.ones(len(simulated.stamps_ns), bool)
    collecting[simulated.still[3][1] + 5] = False  # a paused sample in the motion from pose 4 to pose 5
    cut = motions_between(poses, simulated.stamps_ns, simulated.gyro_radps, collecting=collecting)
    assert len(cut) == len(motions)
    for ours, theirs in zip(cut, motions):
        np.testing.assert_array_equal(ours.stamps_ns, theirs.stamps_ns)
    assert [m.paused for m in cut] == [i == 3 for i in range(len(cut))]


@pytest.mark.parametrize("change, match", [
    (lambda p, m: (p, m[:-1]), "one per pair of consecutive poses"),
    (lambda p, m: ([replace(p[0], gyro_radps=None)] + p[1:], m), "pose 1 has no gyro mean"),
    (lambda p, m: ([p[1], p[0]] + p[2:], m), "time order"),
    (lambda p, m: (p, [Motion(np.arange(5), np.zeros((4, 3)))] + m[1:]), "motion 1"),
])
def test_bad_arguments_are_refused_in_one_line(change, match):
    simulated = simulate_session(np.random.default_rng(43), poses=8)
    poses, motions = poses_and_motions(simulated)
    poses, motions = change(list(poses), list(motions))
    with pytest.raises(CalibrationError, match=match):
        fit_gyro(poses, motions, Calibration(bias=simulated.accel_bias_mps2, matrix=simulated.accel_matrix))


def test_bad_noise_and_initial_matrix_are_refused():
    simulated = simulate_session(np.random.default_rng(44), poses=8)
    poses, motions = poses_and_motions(simulated)
    accel = Calibration(bias=simulated.accel_bias_mps2, matrix=simulated.accel_matrix)
    with pytest.raises(CalibrationError, match="gyro_noise_radps"):
        fit_gyro(poses, motions, accel, gyro_noise_radps=-1.0)
    with pytest.raises(CalibrationError, match="initial_matrix"):
        fit_gyro(poses, motions, accel, initial_matrix=np.zeros((3, 3)))
    with pytest.raises(CalibrationError, match="max_motion_s"):
        GyroFitOptions(max_motion_s=0)


# ------------------------------------------------------------------ the imu_tk Xsens recording
G_XSENS = 9.81744  # the authors' local g


def xsens_session(shared):
    """Poses (our session's detector), the accelerometer fit and the motions between the poses. Counts are
    read with imu_tk's nominal starts: 32768 offset, 4060 counts/g, 6258 counts per rad/s."""
    acc = np.loadtxt(gzip.open(shared("real/imu_tk/xsens_acc.txt.gz")))
    gyr = np.loadtxt(gzip.open(shared("real/imu_tk/xsens_gyro.txt.gz")))
    stamps = (acc[:, 0] * 1e9).astype(np.int64)
    accel = (acc[:, 1:] - 32768) / 4060 * G_XSENS
    gyro = (gyr[:, 1:] - 32768) / 6258.0
    poses = CalibrationSession(Settings(gravity=G_XSENS)).add_recording(stamps, accel, gyro)
    calibration = fit(poses, gravity=G_XSENS).calibration
    still_noise = gyro[stamps < poses[0].end_ns].std(axis=0)
    return poses, calibration, motions_between(poses, stamps, gyro), still_noise


def _imu_tk_integration(motion, matrix, bias):
    """imu_tk's integrateGyroInterval: RK4 of q' = q (x) w / 2 with w linear between samples."""
    rates = (np.asarray(motion.gyro_radps) - bias) @ matrix.T
    q = np.array([1.0, 0, 0, 0])

    def omega(w):
        return 0.5 * np.array([[0, -w[0], -w[1], -w[2]], [w[0], 0, w[2], -w[1]],
                               [w[1], -w[2], 0, w[0]], [w[2], w[1], -w[0], 0]])

    for j in range(len(rates) - 1):
        dt = (motion.stamps_ns[j + 1] - motion.stamps_ns[j]) * 1e-9
        middle = 0.5 * (rates[j] + rates[j + 1])
        k1 = omega(rates[j]) @ q
        k2 = omega(middle) @ (q + 0.5 * dt * k1)
        k3 = omega(middle) @ (q + 0.5 * dt * k2)
        k4 = omega(rates[j + 1]) @ (q + dt * k3)
        q = q + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        q /= np.linalg.norm(q)
    return Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix()


def test_xsens_recording(shared):
    """The imu_tk Xsens MTi session: every motion between the 39 poses is used, the motions miss the next
    pose by ~6 mrad rms (674 mrad with the nominal scale), and imu_tk's own RK4 integration of our M_g agrees."""
    poses, accel, motions, noise = xsens_session(shared)
    result = fit_gyro(poses, motions, accel, gyro_noise_radps=noise)
    assert result.success, result.message
    assert result.motions_used == len(poses) - 1 >= 34 and not result.refused
    assert result.residual_rms_mrad < 7.0 and result.residual_rms_before_mrad > 500
    # The nominal 6258 counts per rad/s is ~31 % off: the scale gate says so; the others pass.
    assert_allclose(np.diag(result.matrix), 1.31, atol=0.01)
    assert GyroGates().check(result).gate is GyroGate.SCALE
    assert GyroGates(scale_band=(0.5, 2.0)).check(result) is None
    assert np.abs(result.matrix[OFF_DIAGONAL]).max() < 0.05  # tens of mrad, as imu_tk finds
    # Our integration against imu_tk's RK4 at our M_g, on three motions.
    directions = accel.apply(np.array([p.accel_mps2 for p in poses]))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    for k in (0, 17, 30):
        samples = motions[k].stamps_ns
        before, after = [0.5 * (p.start_ns + p.end_ns) for p in poses[k:k + 2]]
        share = np.clip((samples - before) / (after - before), 0, 1)[:, None]  # the bias as fit_gyro takes it
        bias = (1 - share) * poses[k].gyro_radps + share * poses[k + 1].gyro_radps
        rotation = _imu_tk_integration(Motion(samples, motions[k].gyro_radps - bias), result.matrix, np.zeros(3))
        theirs_mrad = np.linalg.norm(rotation.T @ directions[k] - directions[k + 1]) * 1e3
        used = result.used.index(k)
        assert abs(theirs_mrad - result.residuals_mrad[used]) < 0.05


def test_against_imu_tks_own_calibration_of_the_xsens_recording(shared):
    """imu_tk's own app (test_imu_calib, g = 9.81744) on the same recording wrote its accelerometer and gyro
    calibrations; both calibrations are scored on the same motions between the same poses, each gravity
    direction from its own accelerometer calibration (a gyro matrix maps into its accelerometer's frame):
    first with the same bias model (interpolated between the poses' gyro means), then as each file
    stands (its one constant bias). Ours misses the next pose by no more than imu_tk's either way."""
    poses, accel, motions, noise = xsens_session(shared)
    ours = fit_gyro(poses, motions, accel, gyro_noise_radps=noise)
    output = shared("real/imu_tk/imu_tk_output")
    their_accel, their_accel_bias = in_our_units(output / "test_imu_acc.calib", 32768.0, 4060 / G_XSENS)
    their_gyro, their_gyro_bias = in_our_units(output / "test_imu_gyro.calib", 32768.0, 6258.0)
    raw = np.array([p.accel_mps2 for p in poses])
    theirs_corrected = (raw - their_accel_bias) @ their_accel.T
    # Read right, imu_tk's accelerometer gives its own g at every pose, and its gyro the same ~1.31 scale.
    assert_allclose(np.linalg.norm(theirs_corrected, axis=1), G_XSENS, atol=0.005)
    assert_allclose(np.diag(their_gyro), np.diag(ours.matrix), atol=0.005)
    their_directions = theirs_corrected / np.linalg.norm(theirs_corrected, axis=1)[:, None]
    our_directions = accel.apply(raw)
    our_directions /= np.linalg.norm(our_directions, axis=1)[:, None]

    def rms(residuals):
        assert np.all(np.isfinite(residuals))
        return float(np.sqrt(np.mean(residuals**2)))

    same_ours = rms(motion_residuals_mrad(poses, motions, our_directions, ours.matrix))
    same_theirs = rms(motion_residuals_mrad(poses, motions, their_directions, their_gyro))
    assert same_ours == pytest.approx(ours.residual_rms_mrad, abs=1e-6)  # the fit's own score, re-scored
    assert same_ours <= same_theirs, f"same bias model: ours {same_ours:.2f} mrad, imu_tk's {same_theirs:.2f} mrad"
    assert 5.5 < same_ours < 6.5 and 6.0 < same_theirs < 7.0, (same_ours, same_theirs)
    filed_ours = rms(motion_residuals_mrad(poses, motions, our_directions, ours.matrix, ours.bias_radps))
    filed_theirs = rms(motion_residuals_mrad(poses, motions, their_directions, their_gyro, their_gyro_bias))
    assert filed_ours <= filed_theirs, f"as filed: ours {filed_ours:.2f} mrad, imu_tk's {filed_theirs:.2f} mrad"
    assert 7.2 < filed_ours < 8.2 and 7.7 < filed_theirs < 8.7, (filed_ours, filed_theirs)


# ------------------------------------------------------------------ gates
def test_gates_name_themselves_and_what_to_do():
    _, good = simulated_fit(11)
    gates = GyroGates()
    assert gates.check(good) is None
    noisy = replace(good, residuals_mrad=good.residuals_mrad * 0 + 12.0)
    assert str(gates.check(noisy)).startswith("gyro: gate residual: motions miss the next pose by 12.0 mrad rms, "
                                              "above 10")
    wrong_units = replace(good, matrix=good.matrix * 57.3)
    assert str(gates.check(wrong_units)).startswith("gyro: gate scale: correction gain x 58.0")
    assert "rad/s" in str(gates.check(wrong_units))
    loose = replace(good, matrix_sigma=good.matrix_sigma * np.array([[1, 1, 100], [1, 1, 100], [1, 1, 100]]))
    assert str(gates.check(loose)).endswith("motions turned about x and y only; turn about z between poses (not about "
                                       "the vertical)")
    assert str(GyroGates(min_motions=20).check(good)).startswith("gyro: gate motions: 17 usable motions between poses, "
                                                            "need 20")
    for bad in (dict(min_motions=2), dict(max_residual_rms_mrad=0), dict(scale_band=(1.0, 1.1))):
        with pytest.raises(CalibrationError):
            GyroGates(**bad)


def test_replay_path_poses_from_the_detector():
    """The poses as our session's detector finds them in a simulated recording, the motions cut between
    them by motions_between: every motion used, the targets met."""
    simulated = simulate_session(np.random.default_rng(1), poses=20, rate_hz=400.0)
    poses = CalibrationSession().add_recording(simulated.stamps_ns, simulated.accel_mps2, simulated.gyro_radps)
    assert len(poses) == 20
    motions = motions_between(poses, simulated.stamps_ns, simulated.gyro_radps)
    result = fit_gyro(poses, motions, fit(poses).calibration, gyro_noise_radps=simulated.gyro_noise_radps)
    assert result.success and result.motions_used == 19 and not result.refused
    scale, misalignment = errors(result, simulated.gyro.matrix)
    assert np.abs(scale).max() < 5e-4 and np.abs(misalignment).max() < 0.3e-3
