"""Fuzzing with hypothesis: arbitrary calibration files and pose tables give a clear CalibrationError
or a valid result -- never a traceback, never a calibration with non-finite or singular terms, and
never a changed output file after a failure."""
import math

import numpy as np
import pytest
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
                             "segment_bounds_degc", "segment_temperatures_degc", "segment_coefficients",
                             "segment_poses", "segment_blend"]),
            st.one_of(numbers, matrices, st.sampled_from(["polynomial", "segmented"])), max_size=7)),
    },
)

from helpers.one_line import assert_at_most_one_line, run_main


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


# ------------------------------------------------------------------ hostile files through the CLI entry

def valid_calibration_text():
    rng = np.random.default_rng(7)
    directions = rng.normal(size=(40, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    temperatures = np.repeat([5.0, 20.0, 35.0, 50.0], 10)
    raw = 9.80665 * directions * [1.01, 0.98, 1.02] + [0.2, -0.3, 0.1] + np.outer(temperatures - 20, [1e-3, -1e-3, 0])
    raw += rng.normal(0, 2e-3, raw.shape)
    result = fit(raw, temperature_degc=temperatures, temperature_model="polynomial")
    assert result.success, result.message
    return yaml.safe_dump(__import__("accel_calibration.io.calibration_file", fromlist=["x"]).calibration_to_dict(
        result.calibration), sort_keys=False).encode()


VALID_CALIBRATION = valid_calibration_text()
VALID_SAMPLES = b"t,ax,ay,az,temperature\n" + b"".join(
    f"{k * 0.01:.2f},{0.2 + k * 1e-3:.6f},{-0.3:.6f},{9.9:.6f},{20 + k * 0.1:.2f}\n".encode() for k in range(30))
byte_changes = st.lists(st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.integers(0, 255)), min_size=1, max_size=6)
insertions = st.sampled_from([b"", b"&a [1, 2]", b"*a", b"[[[[[[[[", b"1e308", b"1.0e+400", b"-", b"\x00",
                              b"\xff\xfe", b",ax", b"\n", b"!!python/object:os.system", b"2024-13-45", b"nan",
                              b"99999999999999999999"])


HOSTILE_VALUES = [b"1.0e+200", b"-1.0e+308", b"1e308", b"1.0e+400", b"9" * 400, b"nan", b".inf", b"2024-13-45", b"",
                  b"[" * 3000 + b"]" * 3000, b"&a [1.0, 2.0, 3.0]", b"*a", b"true", b"'1.0'", b"0", b"-0.0", b"1e-320"]
NUMBER = __import__("re").compile(rb"-?\d+(\.\d+)?(e[+-]?\d+)?")


def mutate(data: bytes, changes, insertion, at) -> bytes:
    out = bytearray(data)
    for where, value in changes:
        out[int(where * len(out))] = value
    position = int(at * len(out))
    return bytes(out[:position]) + insertion + bytes(out[position:])


def replace_numbers(data: bytes, picks) -> bytes:
    """`data` with some of its numbers replaced by hostile values: the structure stays valid, so the
    values reach the checks behind the parser."""
    spans = [m.span() for m in NUMBER.finditer(data)]
    out = data
    for where, value in sorted(((min(int(w * len(spans)), len(spans) - 1), v) for w, v in picks), reverse=True):
        start, end = spans[where]
        out = out[:start] + value + out[end:]
    return out


value_picks = st.lists(st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.sampled_from(HOSTILE_VALUES)),
                       min_size=1, max_size=3, unique_by=lambda pick: pick[0])


@pytest.mark.filterwarnings("error")  # a RuntimeWarning (overflow) escaping is a failure too
@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(changes=byte_changes, insertion=insertions, at=st.floats(0.0, 1.0), picks=value_picks,
       bytes_or_values=st.booleans(), csv_picks=st.one_of(st.none(), value_picks))
def test_mutated_calibration_and_csv_files_through_apply(tmp_path_factory, changes, insertion, at, picks,
                                                         bytes_or_values, csv_picks):
    folder = tmp_path_factory.mktemp("apply")
    cal, data, out = folder / "cal.yaml", folder / "in.csv", folder / "out.csv"
    cal.write_bytes(mutate(VALID_CALIBRATION, changes, insertion, at) if bytes_or_values
                    else replace_numbers(VALID_CALIBRATION, picks))
    data.write_bytes(VALID_SAMPLES if csv_picks is None else replace_numbers(VALID_SAMPLES, csv_picks))
    before = (cal.read_bytes(), data.read_bytes())
    code, err = run_main(["apply", "-c", cal, data, out])
    assert_at_most_one_line(code, err)
    assert (cal.read_bytes(), data.read_bytes()) == before
    if code == 0:
        assert len(out.read_text().splitlines()) == len(data.read_text().splitlines())
    else:
        assert not out.exists()


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(changes=byte_changes, insertion=insertions, at=st.floats(0.0, 1.0), picks=value_picks,
       bytes_or_values=st.booleans(), model=st.sampled_from(["six", "sphere9", "reference12"]))
def test_mutated_pose_tables_through_fit(tmp_path_factory, changes, insertion, at, picks, bytes_or_values, model):
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(20, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    table = "ax,ay,az,ref_x,ref_y,ref_z\n" + "".join(
        ",".join(f"{v:.6f}" for v in np.concatenate([9.80665 * d * 1.01 + 0.1, d])) + "\n" for d in directions)
    folder = tmp_path_factory.mktemp("fit")
    poses, output = folder / "poses.csv", folder / "cal.yaml"
    poses.write_bytes(mutate(table.encode(), changes, insertion, at) if bytes_or_values
                      else replace_numbers(table.encode(), picks))
    before = poses.read_bytes()
    code, err = run_main(["fit", poses, "--model", model, "-o", output])
    assert_at_most_one_line(code, err)
    assert poses.read_bytes() == before
    assert (code == 0) == output.exists()


yaml_leaves = st.one_of(st.floats(), st.integers(), st.text(max_size=6), st.booleans(), st.none())
yaml_trees = st.recursive(yaml_leaves, lambda children: st.one_of(st.lists(children, max_size=4),
                                                                  st.dictionaries(st.text(max_size=4), children,
                                                                                  max_size=4)), max_leaves=30)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(changes=byte_changes, insertion=insertions, at=st.floats(0.0, 1.0), tree=st.one_of(st.none(), yaml_trees))
def test_mutated_calibration_files_through_report(tmp_path_factory, changes, insertion, at, tree):
    folder = tmp_path_factory.mktemp("report")
    cal, poses, output = folder / "cal.yaml", folder / "poses.csv", folder / "r.png"
    if tree is None:
        cal.write_bytes(replace_numbers(VALID_CALIBRATION, [(at, insertion or b"1.0e+200")]))
    else:
        cal.write_text(yaml.safe_dump({"accel_calibration": tree}))
    poses.write_text("ax,ay,az,temperature\n0.2,-0.3,9.9,20\n9.9,-0.3,0.1,30\n0.2,9.5,0.1,40\n")
    before = cal.read_bytes()
    code, err = run_main(["report", cal, "--poses", poses, "-o", output])
    assert_at_most_one_line(code, err)
    assert cal.read_bytes() == before
