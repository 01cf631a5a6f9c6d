"""Quality gates and units detection: nothing implausible is applied, and each refusal names its gate."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from accel_calibration import MG, CalibrationError, Pose
from accel_calibration.core.gates import QualityGates
from accel_calibration.core.session import CalibrationSession
from accel_calibration.core.settings import Settings

G = 9.80665


def poses_from(raw):
    return [Pose(accel_mps2=a, accel_cov=np.eye(3) * 1e-6, samples=200, start_ns=i * 10**9,
                 end_ns=i * 10**9 + 5 * 10**8)
            for i, a in enumerate(raw)]


def session(bias=(0.2, -0.3, 0.1), scale=(1.01, 0.99, 1.02), n=24, noise_mg=0.2, seed=0, directions=None):
    rng = np.random.default_rng(seed)
    if directions is None:
        directions = Rotation.random(n, random_state=rng).apply([0.0, 0.0, 1.0])
        directions[:6] = np.vstack([np.eye(3), -np.eye(3)])
    raw = G * directions / np.array(scale) + np.array(bias) + rng.normal(0, noise_mg * MG, directions.shape)
    return raw


def calibrate(raw, **settings):
    session = CalibrationSession(Settings(**settings))
    for pose in poses_from(raw):
        session.add_pose(pose)
    verdict = session.calibrate()
    return verdict.result, None if verdict.success else verdict.message


def test_a_good_session_passes_every_gate():
    result, problem = calibrate(session())
    assert problem is None and result.success


@pytest.mark.parametrize(
    "raw, gates, gate",
    [
        (session(n=10), {}, "gate poses: have 10 poses, need min_poses=12"),
        (session(noise_mg=30.0), {}, "gate residual"),
        (session(), dict(max_bias_sigma_mg=0.01), "gate sigma: bias"),
        (session(), dict(max_scale_sigma_ppm=1.0), "gate sigma: scale"),
        (session(), dict(max_misalignment_sigma_mrad=0.001), "gate sigma: misalignment"),
        (session(bias=(2.5, 0.0, 0.0)), {}, "gate bias: |b| 2.4"),
        (session(scale=(1.25, 1.0, 1.0)), {}, "gate scale: correction gain x 1.2"),
        (session(scale=(1.05, 1.0, 1.0)), dict(scale_min=0.98, scale_max=1.02), "gate scale"),
    ],
)
def test_each_gate_refuses_with_its_name(raw, gates, gate):
    _, problem = calibrate(raw, **gates)
    assert problem is not None and gate in problem, problem


def test_a_missing_face_alone_is_not_refused_but_a_loose_parameter_is():
    """No coverage gate ("no pose with x pointing down"): what is judged is each
    parameter's sigma against its bound, and the refusal says which orientation would help."""
    rng = np.random.default_rng(3)
    directions = Rotation.random(400, random_state=rng).apply([0.0, 0.0, 1.0])
    directions = directions[directions[:, 0] > -0.5][:30]  # x never points down
    result, problem = calibrate(session(directions=directions))
    assert problem is None and "x pointing down" in result.missing_directions
    _, problem = calibrate(session(directions=directions), max_scale_sigma_ppm=20.0)
    assert problem is not None and problem.startswith("gate sigma: scale x uncertainty"), problem
    assert "turn x down would lower it most" in problem


def test_stream_in_g_is_detected_not_fitted():
    _, problem = calibrate(session() / G)
    assert problem is not None and "looks like g, not m/s^2" in problem


def test_stream_in_raw_counts_is_detected_not_fitted():
    _, problem = calibrate(session() / G * 16384)
    assert problem is not None and "raw sensor counts" in problem


@pytest.mark.parametrize("gates, name", [(dict(min_poses=2), "min_poses"), (dict(max_bias_mps2=-1.0), "max_bias_mps2"),
                                         (dict(scale_min=1.1, scale_max=1.2), "scale_min")])
def test_bad_gate_settings_are_refused(gates, name):
    with pytest.raises(CalibrationError, match=name):
        Settings(**gates)
    with pytest.raises(CalibrationError, match=name.split("_")[0]):
        QualityGates(**{("scale_band" if k.startswith("scale") else k): v for k, v in gates.items()}
                     if "scale_min" not in gates
                     else {"scale_band": (gates["scale_min"], gates["scale_max"])})


@pytest.mark.parametrize("bias", [(0.6, 0.0, 0.0), (float("nan"), 0.0, 0.0)])
def test_the_gates_and_the_file_check_judge_bias_and_scale_by_one_rule(bias):
    """What /calibrate refuses and what the node refuses to put in force agree, text and all: a NaN bias
    (only arrays, not a Calibration, can hold one) is refused by both."""
    from types import SimpleNamespace

    from accel_calibration.core.plausibility import plausibility_refusal

    gates = QualityGates(max_bias_mps2=0.5)
    terms = SimpleNamespace(bias=np.array(bias), matrix=np.eye(3), model="sphere9", quadratic=None,
                            temperature=None, gyro_bias_radps=None, gyro_matrix=None)
    from_gate = gates.plausibility(terms)
    assert from_gate is not None
    assert from_gate == plausibility_refusal(terms, max_bias_mps2=0.5)
    assert str(from_gate).startswith("gate bias: |b| ")


def test_a_verdict_over_the_same_poses_fits_them_once(monkeypatch):
    """The cold fit is a function of the poses: a second verdict over them (an auto-calibration's, then
    /calibrate's) takes the first's fit, and gives the same verdict."""
    import accel_calibration.core.session as session_module

    fits = []
    real_fit = session_module.fit
    monkeypatch.setattr(session_module, "fit", lambda *a, **k: fits.append(1) or real_fit(*a, **k))
    calibration_session = CalibrationSession(Settings())
    _, first = calibration_session.verdict_for(poses_from(session()))
    fitted = len(fits)
    _, second = calibration_session.verdict_for([])
    assert first.success and second.success and fitted >= 1 and len(fits) == fitted
    assert second.message == first.message and second.calibration.bias.tolist() == first.calibration.bias.tolist()
