"""The dividing-head model of Gao et al. (2016): the paper's own simulation through `accel-calib fit`,
exact recovery, agreement with scipy's least squares, the refusals, and the file."""
import re

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares

from accel_calibration import load_calibration
from accel_calibration.cli.main import main
from accel_calibration.core.dividing_head import DividingHeadModel, axes_matrix, nominal_directions
from accel_calibration.core.dividing_head_fit import fit_dividing_head
from accel_calibration.core.errors import CalibrationError
from accel_calibration.core.fit import fit

G = 9.80665
MG = G * 1e-3
# The paper's simulation: K, ∇ (g), δθ, γ, Δβ (rad); 0.15 mg of noise on each axis of each position mean.
PAPER_TRUTH = np.concatenate([
    1 + np.array([0.0002, -0.00012, 0.0003]),
    np.array([1.1, -0.75, 0.8]) * 1e-3,
    np.array([0.22, -0.18, 0.09]) * 1e-3,
    np.array([0.13, -0.12, 0.22]) * 1e-3,
    np.array([1.5, -1.8, -2.1]) * 1e-3,
])
PAPER_NOISE_G = 0.15e-3
ALPHA_DEG = np.tile(np.arange(8) * 45.0, 3)
BETA_DEG = np.repeat([0.0, 45.0, 90.0], 8)


def paper_positions_g(truth=PAPER_TRUTH, alpha_deg=ALPHA_DEG, beta_deg=BETA_DEG):
    """A_i (N, 3) in g at the nominal angles, with the truth's errors."""
    return DividingHeadModel.from_angles(np.radians(alpha_deg), np.radians(beta_deg)).predict(truth)


def terms_vector(terms):
    """The 15 terms of a DividingHeadTerms in the model's units (g, rad) and their sigmas."""
    def vector(source):
        return np.concatenate([source["scale"], np.array(source["bias_mg"]) * 1e-3,
                               np.array(source["mounting_mrad"]) * 1e-3,
                               np.array(source["nonorthogonality_mrad"]) * 1e-3,
                               np.array(source["tilt_error_mrad"]) * 1e-3])
    values = {name: getattr(terms, name) for name in terms.VALUES}
    return vector(values), vector(terms.sigma)


def write_table(path, accel, alpha_deg=ALPHA_DEG, beta_deg=BETA_DEG, positions=False):
    if positions:  # the paper's numbering k-j: β = 45 k, α = 45 (j - 1)
        lines = ["pos,ax,ay,az"] + [f"{int(b // 45)}-{int(a // 45) + 1},{float(x)!r},{float(y)!r},{float(z)!r}"
                                    for a, b, (x, y, z) in zip(alpha_deg, beta_deg, accel)]
    else:
        lines = ["alpha_deg,beta_deg,ax,ay,az"] + [f"{float(a)!r},{float(b)!r},{float(x)!r},{float(y)!r},{float(z)!r}"
                                                   for a, b, (x, y, z) in zip(alpha_deg, beta_deg, accel)]
    path.write_text("\n".join(lines) + "\n")


def test_paper_simulation_through_the_cli(tmp_path, capsys):
    """The paper's simulation, each draw through `accel-calib fit --units g` and its file read back: the
    file holds what the core fit gives (so the coverage below is the command's), the residual sigma is
    the paper's 0.15 mg, and the errors scatter as their sigmas say."""
    rng = np.random.default_rng(2016)
    clean = paper_positions_g()
    alpha, beta = np.radians(ALPHA_DEG), np.radians(BETA_DEG)
    z, noise_mg = [], []
    for _ in range(100):
        noisy = clean + rng.normal(0.0, PAPER_NOISE_G, clean.shape)
        write_table(tmp_path / "head.csv", noisy)
        assert main(["fit", str(tmp_path / "head.csv"), "--model", "dividing-head", "--units", "g",
                     "-o", str(tmp_path / "cal.yaml")]) == 0
        terms = load_calibration(tmp_path / "cal.yaml").dividing_head
        values, sigma = terms_vector(terms)
        core_values, core_sigma = terms_vector(fit_dividing_head(alpha, beta, noisy * G).calibration.dividing_head)
        np.testing.assert_allclose(values, core_values, rtol=0, atol=1e-12)
        np.testing.assert_allclose(sigma, core_sigma, rtol=1e-12, atol=0)
        z.append((values - PAPER_TRUTH) / sigma)
        noise_mg.append(terms.residual_sigma_mg)
    out = capsys.readouterr().out
    assert "dividing head (Gao et al. 2016)" in out and "tilt error Δβ (mrad)" in out and "β 90°:" in out
    assert abs(np.mean(noise_mg) - 0.15) < 0.005  # mg: the paper's noise, recovered from the residuals
    assert 0.10 < min(noise_mg) and max(noise_mg) < 0.21
    # The sigmas are right, not merely generous: each term's normalised error has unit spread.
    spread = np.sqrt((np.array(z) ** 2).mean(axis=0))
    assert np.all(np.abs(spread - 1.0) < 0.2), spread


def test_many_draws_cover_at_three_sigma():
    """Every term's error within 3 of its sigma in >= 99 % of 1000 draws (the core, ~1 ms a fit; the
    command gives the same numbers, above). Student-t with 57 dof: 99.6 % expected."""
    rng = np.random.default_rng(7)
    clean = paper_positions_g() * G
    alpha, beta = np.radians(ALPHA_DEG), np.radians(BETA_DEG)
    z = []
    for _ in range(1000):
        result = fit_dividing_head(alpha, beta, clean + rng.normal(0.0, PAPER_NOISE_G * G, clean.shape))
        values, sigma = terms_vector(result.calibration.dividing_head)
        z.append((values - PAPER_TRUTH) / sigma)
    within = (np.abs(np.array(z)) < 3.0).mean(axis=0)
    assert within.min() >= 0.99, within


def test_zero_noise_returns_the_terms_to_1e_9():
    result = fit_dividing_head(np.radians(ALPHA_DEG), np.radians(BETA_DEG), paper_positions_g() * G)
    assert result.success, result.message
    values, _ = terms_vector(result.calibration.dividing_head)
    np.testing.assert_allclose(values, PAPER_TRUTH, rtol=0, atol=1e-9)
    # And the calibration is the model's: M = (diag(K) C)^-1, b = g ∇.
    forward = axes_matrix(PAPER_TRUTH[6:12]) * PAPER_TRUTH[:3, None]
    np.testing.assert_allclose(result.calibration.matrix, np.linalg.inv(forward), rtol=0, atol=1e-9)
    np.testing.assert_allclose(result.calibration.bias, PAPER_TRUTH[3:6] * G, rtol=0, atol=1e-8)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), tilts=st.sampled_from([(0, 45, 90), (0, 30, 60, 90), (-30, 20, 70),
                                                              (10, 50, 90), (0, 45, 90, 135)]),
       alphas=st.integers(3, 12))
def test_any_complete_protocol_recovers_the_terms_exactly(seed, tilts, alphas):
    """Any β set of three or more, any number of α (>= 3, evenly spread from a random start): zero noise
    gives the terms back to 1e-9, whatever they are within a few mrad and per mille."""
    rng = np.random.default_rng(seed)
    truth = np.concatenate([1 + rng.uniform(-3e-3, 3e-3, 3), rng.uniform(-5e-3, 5e-3, 3),
                            rng.uniform(-3e-3, 3e-3, 6), rng.uniform(-3e-3, 3e-3, len(tilts))])
    alpha = np.tile(rng.uniform(0, 360) + np.arange(alphas) * 360.0 / alphas, len(tilts))
    beta = np.repeat(np.array(tilts, dtype=float), alphas)
    result = fit_dividing_head(np.radians(alpha), np.radians(beta), paper_positions_g(truth, alpha, beta) * G)
    assert result.success, result.message
    values, _ = terms_vector(result.calibration.dividing_head)
    np.testing.assert_allclose(values, truth, rtol=0, atol=1e-9)
    assert result.calibration.dividing_head.tilt_deg == tuple(float(t) for t in tilts)


def test_equals_scipy_least_squares():
    """The same minimum as scipy's least squares on the model (its own finite-difference Jacobian)."""
    rng = np.random.default_rng(3)
    measured_g = paper_positions_g() + rng.normal(0.0, PAPER_NOISE_G, (24, 3))
    alpha, beta = np.radians(ALPHA_DEG), np.radians(BETA_DEG)
    model = DividingHeadModel.from_angles(alpha, beta)
    ours, _ = terms_vector(fit_dividing_head(alpha, beta, measured_g * G).calibration.dividing_head)
    theirs = least_squares(lambda p: model.residual_and_jacobian(p, measured_g)[0], model.seed(measured_g),
                           jac="3-point", method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-9)


def test_analytic_jacobian_matches_differences():
    model = DividingHeadModel.from_angles(np.radians(ALPHA_DEG), np.radians(BETA_DEG))
    p = PAPER_TRUTH + 2e-3
    measured = paper_positions_g()
    _, jacobian = model.residual_and_jacobian(p, measured)
    step = 1e-6
    def residual(x):
        return model.residual_and_jacobian(x, measured)[0]

    numeric = np.column_stack([(residual(p + step * e) - residual(p - step * e)) / (2 * step) for e in np.eye(len(p))])
    np.testing.assert_allclose(jacobian, numeric, rtol=0, atol=1e-9)


def test_reference12_with_the_nominal_angles_is_biased_by_the_tilt_errors():
    """The number docs/dividing_head.md quotes: fitting the same noise-free table as reference12 with the
    nominal directions puts the tilt errors into M (2.0e-3 on M_xx, 0.6e-3 on M_yy, M_zz) and b_x (1.2 mg)."""
    clean = paper_positions_g() * G
    alpha, beta = np.radians(ALPHA_DEG), np.radians(BETA_DEG)
    reference = fit(clean, model="reference12", reference=nominal_directions(alpha, beta))
    head = fit_dividing_head(alpha, beta, clean)
    matrix_error = reference.calibration.matrix - head.calibration.matrix
    bias_error_mg = (reference.calibration.bias - head.calibration.bias) / MG
    np.testing.assert_allclose(np.diag(matrix_error) * 1e3, [1.953, -0.598, -0.598], atol=0.002)
    assert np.abs(matrix_error - np.diag(np.diag(matrix_error))).max() < 1e-6  # misalignment barely moves
    np.testing.assert_allclose(bias_error_mg, [-1.184, 0.0, 0.0], atol=0.002)
    assert reference.calibration.quality.residual_rms_mg > 1.5  # it cannot fit the table: 1.56 mg rms
    assert head.calibration.quality.residual_rms_mg < 1e-9


def test_the_pos_column_and_g_units_give_the_same_calibration(tmp_path):
    rng = np.random.default_rng(5)
    accel_g = paper_positions_g() + rng.normal(0.0, PAPER_NOISE_G, (24, 3))
    write_table(tmp_path / "angles.csv", accel_g * G)
    write_table(tmp_path / "pos.csv", accel_g, positions=True)
    assert main(["fit", str(tmp_path / "angles.csv"), "--model", "dividing-head", "-o", str(tmp_path / "a.yaml")]) == 0
    assert main(["fit", str(tmp_path / "pos.csv"), "--model", "dividing-head", "--units", "g",
                 "-o", str(tmp_path / "b.yaml")]) == 0
    a, b = load_calibration(tmp_path / "a.yaml"), load_calibration(tmp_path / "b.yaml")
    np.testing.assert_allclose(a.matrix, b.matrix, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.bias, b.bias, rtol=0, atol=1e-12)
    assert a.dividing_head.tilt_deg == (0.0, 45.0, 90.0)


def test_the_file_holds_the_papers_terms_and_apply_uses_m_and_b(tmp_path):
    rng = np.random.default_rng(6)
    accel = (paper_positions_g() + rng.normal(0.0, PAPER_NOISE_G, (24, 3))) * G
    write_table(tmp_path / "head.csv", accel)
    assert main(["fit", str(tmp_path / "head.csv"), "--model", "dividing-head", "-o", str(tmp_path / "cal.yaml")]) == 0
    body = yaml.safe_load((tmp_path / "cal.yaml").read_text())["accel_calibration"]
    assert body["model"] == "dividing-head"
    block = body["dividing_head"]
    assert block["tilt_deg"] == [0.0, 45.0, 90.0] and len(block["tilt_error_mrad"]) == 3
    assert set(block["sigma"]) == {"scale", "bias_mg", "mounting_mrad", "nonorthogonality_mrad", "tilt_error_mrad"}
    assert np.all(np.abs(np.array(block["tilt_error_mrad"]) - [1.5, -1.8, -2.1])
                  < 3 * np.array(block["sigma"]["tilt_error_mrad"]))
    calibration = load_calibration(tmp_path / "cal.yaml")
    result = fit_dividing_head(np.radians(ALPHA_DEG), np.radians(BETA_DEG), accel)
    assert calibration.dividing_head == result.calibration.dividing_head  # the round trip is exact
    # `apply` corrects with M and b (and its plausibility gates accept the model), as for reference12.
    rows = "\n".join(",".join(repr(float(v)) for v in row) for row in accel)
    (tmp_path / "raw.csv").write_text("ax,ay,az\n" + rows + "\n")
    assert main(["apply", "-c", str(tmp_path / "cal.yaml"), str(tmp_path / "raw.csv"), str(tmp_path / "out.csv")]) == 0
    out = np.loadtxt(tmp_path / "out.csv", delimiter=",", skiprows=1)
    true_directions = nominal_directions(np.radians(ALPHA_DEG),
                                         np.radians(BETA_DEG) + np.repeat(PAPER_TRUTH[12:], 8))
    # Noise-level errors, not reference12's mg:
    assert np.abs(np.linalg.norm(out - G * true_directions, axis=1)).max() < 0.8 * MG


@pytest.mark.parametrize("alpha_deg, beta_deg, message", [
    (np.tile([0.0, 180.0], 3), np.repeat([0.0, 45.0, 90.0], 2), r"tilt β = 0° has 2 distinct α \(0°, 180°\)"),
    (np.tile([0.0, 45.0, 90.0], 3), np.repeat([0.0, 45.0, 90.0], 3),
     r"at tilt β = 0° the α leave 270° of the circle empty .* not observable"),
    (np.arange(8) * 45.0, np.full(8, 90.0), r"every position is at β = 90°: .* cannot be separated"),
    (np.arange(8) * 45.0, np.full(8, 45.0), r"every position is at β = 45°"),
    (np.tile(np.arange(8) * 45.0, 2), np.repeat([0.0, 90.0], 8), r"2 tilts \(β = 0°, 90°\) .* a third β"),
])
def test_refusals_are_one_line(tmp_path, capsys, alpha_deg, beta_deg, message):
    result = fit_dividing_head(np.radians(alpha_deg), np.radians(beta_deg), np.tile([0.0, 0.0, G], (len(alpha_deg), 1)))
    assert not result.success
    assert re.search(message, result.message), result.message
    write_table(tmp_path / "t.csv", np.tile([0.0, 0.0, G], (len(alpha_deg), 1)), alpha_deg, beta_deg)
    assert main(["fit", str(tmp_path / "t.csv"), "--model", "dividing-head", "-o", str(tmp_path / "c.yaml")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("accel-calib: error: fit failed: ") and err.count("\n") == 1
    assert not (tmp_path / "c.yaml").exists()


def test_an_ill_conditioned_protocol_is_refused():
    """Three tilts within 2° of each other: complete by the protocol's rules, but the tilt errors are set by
    noise; the condition number refuses it."""
    alpha = np.tile(np.arange(8) * 45.0, 3)
    beta = np.repeat([0.0, 1.0, 2.0], 8)
    accel = paper_positions_g(alpha_deg=alpha, beta_deg=beta) * G
    result = fit_dividing_head(np.radians(alpha), np.radians(beta), accel)
    assert not result.success and "do not determine the 15 terms" in result.message


@pytest.mark.parametrize("header, row, message", [
    ("pos,ax,ay,az", "1-0,0,0,1", r"row 2, column pos: '1-0' is not a position k-j"),
    ("pos,ax,ay,az", "x,0,0,1", r"column pos: 'x' is not a position"),
    ("alpha_deg,ax,ay,az", "0,0,0,1", r"needs the columns alpha_deg,beta_deg"),
    ("pos,alpha_deg,beta_deg,ax,ay,az", "1-1,0,0,0,0,1", r"either as alpha_deg,beta_deg or as a 'pos'"),
    ("alpha_deg,beta_deg,ax,ay,az", "nan,0,0,0,1", r"column alpha_deg: 'nan' is not an angle"),
])
def test_bad_tables_are_one_line(tmp_path, capsys, header, row, message):
    (tmp_path / "t.csv").write_text(f"{header}\n{row}\n")
    assert main(["fit", str(tmp_path / "t.csv"), "--model", "dividing-head", "-o", str(tmp_path / "c.yaml")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert re.search(message, err), err


def test_bad_arguments_raise_calibration_error():
    with pytest.raises(CalibrationError, match="alpha_rad must hold one angle per position"):
        fit_dividing_head(np.zeros(3), np.zeros(4), np.zeros((4, 3)))
    with pytest.raises(CalibrationError, match="accel_mps2 has a non-finite value"):
        fit_dividing_head(np.zeros(2), np.zeros(2), [[0, 0, np.nan], [0, 0, 1]])
    with pytest.raises(CalibrationError, match="gravity must be a positive number"):
        fit_dividing_head(np.zeros(1), np.zeros(1), [[0, 0, 1]], gravity=-1.0)


@pytest.mark.parametrize("edit, message", [
    (lambda b: b["dividing_head"].pop("sigma"), "dividing_head is missing sigma"),
    (lambda b: b["dividing_head"].__setitem__("scale", [1.0, "1e5", 1.0]), r"scale must be a list of numbers"),
    (lambda b: b["dividing_head"].__setitem__("tilt_error_mrad", [1.0]), "one number per tilt_deg"),
    (lambda b: b["dividing_head"]["sigma"].__setitem__("bias_mg", [0.1, -0.1, 0.1]), "sigma.bias_mg must hold 3"),
    (lambda b: b.__setitem__("model", "reference12"), "a dividing_head block belongs to model dividing-head"),
    (lambda b: b.__setitem__("dividing_head", [1, 2]), "dividing_head must be a mapping"),
])
def test_a_bad_dividing_head_block_is_refused_in_one_line(tmp_path, edit, message):
    from accel_calibration.io.calibration_file import CalibrationFileError, calibration_from_dict, calibration_to_dict

    result = fit_dividing_head(np.radians(ALPHA_DEG), np.radians(BETA_DEG), paper_positions_g() * G)
    document = calibration_to_dict(result.calibration)
    assert calibration_from_dict(document) == result.calibration
    edit(document["accel_calibration"])
    with pytest.raises(CalibrationFileError, match=message):
        calibration_from_dict(document, "cal.yaml")
