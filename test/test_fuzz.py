"""Fuzzing with hypothesis: arbitrary calibration files and pose tables give a clear CalibrationError
or a valid result -- never a traceback, never a calibration with non-finite or singular terms, and
never a changed output file after a failure."""
import math

import numpy as np
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from accel_calibration import Calibration, CalibrationError, fit, load_calibration, save_calibration
from accel_calibration.cli.main import main
from accel_calibration.io.calibration_file import calibration_from_yaml

FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**12, 10**12), st.text(max_size=4),
                    st.booleans(), st.none())
vectors = st.one_of(st.lists(numbers, max_size=4), numbers, st.dictionaries(st.text(max_size=3), numbers, max_size=2))
matrices = st.one_of(st.lists(st.lists(numbers, max_size=4), max_size=4), vectors)
bodies = st.fixed_dictionaries(
    {},
    optional={
        "format_version": st.one_of(st.integers(-2, 5), numbers),
        "model": st.one_of(st.sampled_from(["six", "sphere9", "reference12", "reference15", "bogus"]), numbers),
        "gravity": numbers,
        "bias": vectors,
        "matrix": matrices,
        "quality": st.one_of(st.dictionaries(st.sampled_from(["residual_rms_mg", "residual_max_mg", "poses",
                                                              "condition_number"]),
                                             numbers, max_size=4), numbers),
        "uncertainty": st.one_of(st.dictionaries(st.sampled_from(["bias", "matrix"]), matrices, max_size=2), numbers),
        "quadratic": vectors,
        "gyro_bias_radps": vectors,
        "temperature": st.one_of(numbers, st.dictionaries(
            st.sampled_from(["model", "reference_degc", "range_degc", "bias_coefficients", "scale_coefficients",
                             "segment_edges_degc", "segment_coefficients"]),
            st.one_of(numbers, matrices, st.sampled_from(["polynomial", "segmented"])), max_size=7)),
    },
)


def assert_usable(calibration: Calibration):
    assert np.all(np.isfinite(calibration.bias)) and np.all(np.isfinite(calibration.matrix))
    assert abs(np.linalg.det(calibration.matrix)) > 0
    corrected = calibration.apply(np.array([[0.1, 0.2, 9.8]]), 25.0)
    assert corrected.shape == (1, 3)


@FUZZ
@given(body=bodies)
def test_arbitrary_calibration_files_load_or_refuse_clearly(body):
    text = yaml.safe_dump({"accel_calibration": body})
    try:
        calibration = calibration_from_yaml(text, "fuzz.yaml")
    except CalibrationError as error:
        assert str(error).startswith("fuzz.yaml") and "\n" not in str(error)
        return
    assert_usable(calibration)


@FUZZ
@given(text=st.text(max_size=200))
def test_arbitrary_text_as_a_calibration_file(text):
    try:
        calibration_from_yaml(text, "fuzz.yaml")
    except CalibrationError as error:
        assert "\n" not in str(error)


finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)


@FUZZ
@given(rows=st.lists(st.tuples(finite, finite, finite), max_size=40),
       model=st.sampled_from(["six", "sphere9"]),
       gravity=st.floats(min_value=0.1, max_value=100.0))
def test_arbitrary_pose_tables_fit_or_report(rows, model, gravity):
    try:
        result = fit(np.array(rows, dtype=float).reshape(-1, 3), model=model, gravity=gravity)
    except CalibrationError:
        return
    if result.success:
        assert_usable(result.calibration)
        assert math.isfinite(result.calibration.quality.residual_rms_mg)
    else:
        assert result.message and result.calibration is None


cells = st.one_of(finite.map(repr), st.sampled_from(["nan", "inf", "", "x", "1e999", "-", "0x10"]), st.text(max_size=5))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(header=st.lists(st.sampled_from(["ax", "ay", "az", "temperature", "ref_x", "ref_y", "ref_z", "t", "AX", ""]),
                       max_size=6),
       rows=st.lists(st.lists(cells, max_size=7), max_size=15),
       model=st.sampled_from(["sphere9", "six", "reference12"]))
def test_cli_on_arbitrary_csv_never_tracebacks_and_keeps_the_output(tmp_path_factory, header, rows, model):
    folder = tmp_path_factory.mktemp("fuzz")
    (folder / "poses.csv").write_text("\n".join([",".join(header)] + [",".join(r) for r in rows]) + "\n")
    output = folder / "cal.yaml"
    save_calibration(Calibration.identity(), output)
    before = output.read_bytes()
    code = main(["fit", str(folder / "poses.csv"), "--model", model, "-o", str(output)])
    if code != 0:
        assert output.read_bytes() == before
    else:
        assert_usable(load_calibration(output))
