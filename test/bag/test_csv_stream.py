"""CSV streams of raw samples: real recordings from ../shared/data/real/ written as the CSV a logger would
write, read back through `accel-calib replay` and compared with the Python API on the same arrays; the
layout rules (time units, column order, delimiters, empty temperature cells) and bad files."""
from __future__ import annotations

import csv
import gzip
import io

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from accel_calibration import load_calibration
from accel_calibration.bag.csv_stream import CsvStreamError, read_csv_stream
from accel_calibration.bag.replay import ReplaySettings, replay_bag
from accel_calibration.cli.main import main
from accel_calibration.core.session import CalibrationSession
from accel_calibration.core.settings import Settings
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

G = 9.80665


def python_api(t_ns, accel, gyro, session_settings, temperature=None):
    """What a user of the Python API gets from the same arrays (README: the session)."""
    session = CalibrationSession(session_settings)
    poses = session.add_recording(t_ns, accel, gyro, *(temperature or (None, None)))
    for pose in poses:
        session.add_pose(pose)
    return poses, session.calibrate()


def write_csv(path, header, columns, formats):
    rows = zip(*[[fmt % v for v in np.asarray(column).tolist()] for column, fmt in zip(columns, formats)])
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(row) for row in rows) + "\n")


def assert_same_result(replay, poses, verdict, tolerance=1e-9):
    def spans(found):
        return [(p.start_ns, p.end_ns, p.samples) for p in found]

    assert spans(replay.poses) == spans(poses)
    for mine, theirs in zip(replay.poses, poses):
        np.testing.assert_allclose(mine.accel_mps2, theirs.accel_mps2, rtol=0, atol=tolerance)
    assert verdict.result is not None and verdict.result.calibration is not None
    ours, reference = replay.result.calibration, verdict.result.calibration
    np.testing.assert_allclose(ours.bias, reference.bias, rtol=0, atol=tolerance)
    np.testing.assert_allclose(ours.matrix, reference.matrix, rtol=0, atol=tolerance)


def test_imu_tk_xsens_as_a_csv_stream_equals_the_python_api(shared, tmp_path):
    """Xsens MTi, 100 Hz: unsigned 16-bit counts centred on 32768, ~4060 counts/g. A logger of this part
    would write signed counts; the gyro goes in as rad/s at a nominal 109 counts per deg/s."""
    acc = np.loadtxt(gzip.open(shared("real/imu_tk/xsens_acc.txt.gz")))
    gyr = np.loadtxt(gzip.open(shared("real/imu_tk/xsens_gyro.txt.gz")))
    np.testing.assert_array_equal(acc[:, 0], gyr[:, 0])
    counts = acc[:, 1:] - 32768.0
    gyro = np.radians((gyr[:, 1:] - 32768.0) / 109.0)
    path = tmp_path / "xsens.csv"
    write_csv(path, ["t", "ax", "ay", "az", "gx", "gy", "gz"], [acc[:, 0], *counts.T, *gyro.T],
              ["%r", "%.0f", "%.0f", "%.0f", "%r", "%r", "%r"])
    settings_ = Settings(gravity=9.81744)  # the authors' local g
    replay = replay_bag(path, ReplaySettings(session=settings_, units="counts", counts_per_g=4060.0))
    t_ns = np.round(acc[:, 0] * 1e9).astype(np.int64)
    accel = counts * (G / 4060.0)
    np.testing.assert_array_equal(replay.source.recording.t_ns, t_ns)
    np.testing.assert_array_equal(replay.source.recording.accel_mps2, accel)
    poses, verdict = python_api(t_ns, accel, gyro, settings_)
    assert 30 <= len(poses) <= 42  # imu_tk's detector finds 38 still intervals
    assert_same_result(replay, poses, verdict)
    assert verdict.success == (replay.calibration is not None)


def test_mpu6050_as_a_csv_stream_equals_the_python_api(shared, tmp_path):
    """MPU-6050 at 100 Hz, int16 counts: 16384 per g (+-2 g), gyro 131 per deg/s (+-250 deg/s)."""
    with open(shared("real/mpu6050_tomisuarez2/example_data_calibration.csv")) as f:
        data = np.array(list(csv.reader(f))[6:], dtype=float)
    t_s = np.arange(len(data)) / 100.0
    gyro = np.radians(data[:, 3:] / 131.0)
    path = tmp_path / "mpu.csv"
    write_csv(path, ["t", "ax", "ay", "az", "gx", "gy", "gz"], [t_s, *data[:, :3].T, *gyro.T],
              ["%r", "%d", "%d", "%d", "%r", "%r", "%r"])
    settings_ = Settings(min_poses=10)  # this session has ten still intervals (its reference says so)
    t_ns = np.arange(len(data), dtype=np.int64) * 10_000_000
    accel = data[:, :3] * (G / 16384.0)
    poses, verdict = python_api(t_ns, accel, gyro, settings_)
    assert len(poses) == 10
    out = tmp_path / "poses.csv"
    code = main(["replay", str(path), "--units", "counts", "--counts-per-g", "16384", "--min-poses", "10",
                 "--poses-out", str(out)])
    assert code == (0 if verdict.success else 1)
    replay = replay_bag(path, ReplaySettings(session=settings_, units="counts", counts_per_g=16384.0))
    np.testing.assert_array_equal(replay.source.recording.t_ns, t_ns)
    assert_same_result(replay, poses, verdict)
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    assert [int(r["start_ns"]) for r in rows] == [p.start_ns for p in poses]
    np.testing.assert_allclose([[float(r[a]) for a in ("ax", "ay", "az")] for r in rows],
                               [p.accel_mps2 for p in poses], rtol=1e-15)


def session_arrays(rng, n=3000, rate_hz=200.0):
    t_ns = (np.arange(n) * (1e9 / rate_hz)).astype(np.int64) + 7_000_000_000
    accel = rng.normal(0, 0.01, (n, 3)) + [0.1, -0.2, G]
    gyro = rng.normal(0, 0.001, (n, 3))
    return t_ns, accel, gyro


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(order=st.permutations(range(8)), delimiter=st.sampled_from([",", ";", "\t"]),
       upper=st.booleans(), crlf=st.booleans())
def test_column_order_case_delimiter_and_extra_columns_do_not_matter(tmp_path, order, delimiter, upper, crlf):
    rng = np.random.default_rng(1)
    t_ns, accel, gyro = session_arrays(rng, n=200)
    temperature = np.where(np.arange(200) % 10 == 0, 25.0 + np.arange(200) / 100, np.nan)
    names = ["t_ns", "ax", "ay", "az", "gx", "gy", "gz", "temperature", "note"]
    columns = [t_ns.astype(str), *(np.char.mod("%.17g", c) for c in (*accel.T, *gyro.T)),
               np.where(np.isnan(temperature), "", np.char.mod("%.17g", temperature)), np.full(200, "x")]
    chosen = [*order, 8]
    header = [names[i].upper() if upper else names[i] for i in chosen]
    lines = [delimiter.join(header)] + [delimiter.join(columns[i][r] for i in chosen) for r in range(200)]
    path = tmp_path / "s.csv"
    path.write_bytes(("\r\n" if crlf else "\n").join(lines).encode() + b"\n")
    samples = read_csv_stream(path)
    np.testing.assert_array_equal(samples.t_ns, t_ns)
    np.testing.assert_array_equal(samples.accel_mps2, accel)
    np.testing.assert_array_equal(samples.gyro_radps, gyro)
    have = ~np.isnan(temperature)  # empty cells: no reading on that row
    np.testing.assert_array_equal(samples.temperature[0], t_ns[have])
    np.testing.assert_array_equal(samples.temperature[1], temperature[have])


@pytest.mark.parametrize("column, unit, scale", [("t", None, 1e-9), ("t", "ms", 1e-6), ("t", "us", 1e-3),
                                                 ("t_ns", None, 1), ("t", "ns", 1)])
def test_time_units(tmp_path, column, unit, scale):
    t_ns = np.arange(50, dtype=np.int64) * 2_500_000 + 1_000_000_000  # 400 Hz from 1 s
    values = t_ns * scale if scale != 1 else t_ns
    path = tmp_path / "t.csv"
    text = [f"{column},ax,ay,az"] + [f"{v!r},0,0,{G}" if scale != 1 else f"{v},0,0,{G}" for v in values.tolist()]
    path.write_text("\n".join(text) + "\n")
    np.testing.assert_array_equal(read_csv_stream(path, time_unit=unit).t_ns, t_ns)


def test_units_g_and_counts(tmp_path):
    rng = np.random.default_rng(2)
    t_ns, accel, _ = session_arrays(rng, n=100)
    for units, per_mps2, extra in (("g", 1 / G, {}), ("counts", 16384 / G, {"counts_per_g": 16384.0})):
        path = tmp_path / f"{units}.csv"
        write_csv(path, ["t_ns", "ax", "ay", "az"], [t_ns, *(accel * per_mps2).T], ["%d", "%r", "%r", "%r"])
        samples = read_csv_stream(path, units=units, **extra)
        np.testing.assert_allclose(samples.accel_mps2, accel, rtol=1e-15, atol=0)
        assert samples.gyro_radps is None and samples.temperature is None


BAD = [
    ("ax,ay,az\n0,0,9.8\n", [], "no time column (t in seconds, or t_ns)"),
    ("t,ax,ay\n0,0,9.8\n", [], "missing column(s) az"),
    ("t,ax,ay,az,gx\n0,0,0,9.8,0\n", [], "gyro columns must be all of gx,gy,gz or none"),
    ("t,ax,ay,az\n0.00,0,0,9.8\n0.01,0,0,9.8\n0.01,0,0,9.8\n", [], "data row 3: time 0.01 s does not increase"),
    ("t,ax,ay,az\n0.00,0,0,9.8\n0.02,0,0,9.8\n0.01,0,0,9.8\n", [], "data row 3: time 0.01 s does not increase"),
    ("t,ax,ay,az\n0.00,0,0,9.8\n,0,0,9.8\n", [], "data row 2, column t: no time"),
    ("t,ax,ay,az\n0.00,0,0,9.8\n0.01,0,zero,9.8\n", [], "line 3, column ay: 'zero' is not a number"),
    ("t,ax,ay,az\n0.00,0,0,9.8\n0.01,0,0\n", [], "line 3 has 3 fields, the header has 4"),
    ("t_ns,ax,ay,az\n1.5,0,0,9.8\n", [], "line 2, column t_ns: '1.5' is not an integer"),
    ("t,ax,ay,az\n", [], "header only, no samples"),
    ("\n", [], "empty first line"),
    ("t,ax,ay,az\n0,0,0,9.8\n", ["--units", "g"], "--units g the samples' median |a| is 96.11 m/s^2"),
    ("t,ax,ay,az\n0,0,0,1.0\n", [], "the file looks like g: use --units g"),
    ("t,ax,ay,az\n0,0,0,16384\n", ["--units", "counts"], "--units counts needs --counts-per-g"),
    ("t,ax,ay,az\n0,0,0,16384\n", ["--units", "counts", "--counts-per-g", "4096"],
     "implausible for a recording at rest (expected ~9.81)"),
    ("t,ax,ay,az\n0,0,0,16384\n", [], "looks like raw counts (~16384 per g): use --units counts --counts-per-g N"),
    ("t,ax,ay,az\n0,0,0,9.8\n", ["--counts-per-g", "4096"], "--counts-per-g applies to --units counts only"),
    ("t,ax,ay,az\n0,0,0,9.8\n", ["--instance", "1"], "--instance does not apply to a csv recording"),
    ("t,ax,ay,az\n0,0,0,9.8\n", ["--time-unit", "h"], "argument --time-unit: invalid choice"),
]


@pytest.mark.parametrize("text, flags, message", BAD)
def test_bad_csv_is_one_line_and_nothing_written(tmp_path, capsys, text, flags, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    outputs = [tmp_path / "cal.yaml", tmp_path / "poses.csv", tmp_path / "corrected.csv"]
    code = main(["replay", str(path), *flags, "-o", str(outputs[0]), "--poses-out", str(outputs[1]),
                 "--corrected", str(outputs[2])])
    err = capsys.readouterr().err
    assert code in (1, 2) and err.count("\n") == 1 and "Traceback" not in err
    assert message in err, err
    assert not any(p.exists() for p in outputs)


def test_not_utf8_and_binary_are_one_line(tmp_path):
    for content, message in ((b"t,ax,ay,az\n\xff\xfe,1,2,3\n", "not a readable CSV"),
                             (b"t,ax,\x00ay,az\n", "binary content")):
        path = tmp_path / "x.csv"
        path.write_bytes(content)
        with pytest.raises(CsvStreamError, match=message):
            read_csv_stream(path)


def test_a_stream_without_gyro_calibrates_from_the_accelerometer_alone(tmp_path):
    rng = np.random.default_rng(12)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    samples = SyntheticImu(errors, spread_orientations(14, rng), dwell_s=2.5, move_s=1.0, rate_hz=200.0,
                           seed=12).samples()
    path = tmp_path / "accel_only.csv"
    write_csv(path, ["t_ns", "ax", "ay", "az"], [samples.t_ns, *samples.accel_raw.T], ["%d", "%r", "%r", "%r"])
    cal = tmp_path / "cal.yaml"
    assert main(["replay", str(path), "-o", str(cal)]) == 0
    replay = replay_bag(path)
    assert len(replay.poses) >= 13 and all(p.gyro_radps is None for p in replay.poses)
    calibration = load_calibration(cal)
    assert calibration.gyro_bias_radps is None  # no gyro, no gyro bias (not a made-up zero)
    assert np.all(np.abs(calibration.bias - errors.bias_mps2) <= 4 * calibration.bias_sigma)
