"""accel-calib from the outside: real processes for the entry point, main() for the many bad inputs."""
import subprocess

import numpy as np
import pytest
import yaml

from accel_calibration import Calibration, load_calibration, save_calibration
from accel_calibration.cli.main import main
from msg_tools.node_process import installed_command

G = 9.80665
ACCEL_CALIB = installed_command("accel-calib")


def write_poses(path, rng, n=20, units="mps2", temperature=False):
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    directions[:6] = np.vstack([np.eye(3), -np.eye(3)])
    matrix = np.array([[1.02, 0, 0], [0.01, 0.98, 0], [-0.005, 0.008, 1.01]])
    bias = np.array([0.25, -0.4, 0.15])
    raw = (G * directions) @ np.linalg.inv(matrix).T + bias + rng.normal(0, 0.001, (n, 3))
    if units == "g":
        raw = raw / G
    header = "ax,ay,az" + (",temperature" if temperature else "")
    lines = [header] + [
        ",".join(f"{v:.9f}" for v in row) + (f",{20 + i * 0.1:.2f}" if temperature else "") for i, row in enumerate(raw)
    ]
    path.write_text("\n".join(lines) + "\n")
    return bias, matrix


def test_fit_then_apply_as_a_user_would(tmp_path):
    rng = np.random.default_rng(1)
    bias, matrix = write_poses(tmp_path / "poses.csv", rng, temperature=True)
    run = subprocess.run(
        [*ACCEL_CALIB, "fit", tmp_path / "poses.csv", "--output", tmp_path / "cal.yaml"],
        capture_output=True, text=True, check=False,
    )
    assert run.returncode == 0, run.stderr
    assert "residuals: rms" in run.stdout and "±" in run.stdout
    cal = load_calibration(tmp_path / "cal.yaml")
    np.testing.assert_allclose(cal.bias, bias, atol=0.003)
    np.testing.assert_allclose(cal.matrix, matrix, atol=5e-4)

    (tmp_path / "in.csv").write_text("t,ax,ay,az\n1.5,0.25,-0.4,10.0\n2.5,10.0,-0.4,0.15\n")
    run = subprocess.run(
        [*ACCEL_CALIB, "apply", "--calibration", tmp_path / "cal.yaml", tmp_path / "in.csv",
         tmp_path / "out.csv"],
        capture_output=True, text=True, check=False,
    )
    assert run.returncode == 0, run.stderr
    out = np.genfromtxt(tmp_path / "out.csv", delimiter=",", names=True)
    np.testing.assert_array_equal(out["t"], [1.5, 2.5])  # other columns pass through
    expected = cal.apply([[0.25, -0.4, 10.0], [10.0, -0.4, 0.15]])
    np.testing.assert_allclose(np.column_stack([out["ax"], out["ay"], out["az"]]), expected, rtol=1e-12)


def test_units_g_gives_the_same_calibration(tmp_path):
    write_poses(tmp_path / "mps2.csv", np.random.default_rng(4))
    write_poses(tmp_path / "g.csv", np.random.default_rng(4), units="g")
    assert main(["fit", str(tmp_path / "mps2.csv"), "-o", str(tmp_path / "a.yaml")]) == 0
    assert main(["fit", str(tmp_path / "g.csv"), "--units", "g", "-o", str(tmp_path / "b.yaml")]) == 0
    a, b = load_calibration(tmp_path / "a.yaml"), load_calibration(tmp_path / "b.yaml")
    np.testing.assert_allclose(a.bias, b.bias, atol=1e-6)
    np.testing.assert_allclose(a.matrix, b.matrix, atol=1e-8)


def test_song_qin_table_through_the_cli(tmp_path, shared):
    table = shared("literature/six_position_song_qin_2009.csv")
    assert main(["fit", str(table), "--units", "g", "--model", "reference15", "-o", str(tmp_path / "c.yaml")]) == 0
    body = yaml.safe_load((tmp_path / "c.yaml").read_text())["accel_calibration"]
    assert body["model"] == "reference15"
    assert body["bias"][0] / G == pytest.approx(-0.0007860575, abs=5e-10)


BAD_INPUTS = {
    "empty": (b"", "empty file"),
    "header only": (b"ax,ay,az\n", "header only"),
    "non-numeric": (b"ax,ay,az\n1,2,3\n1,abc,3\n", "row 3, column ay: 'abc' is not a number"),
    "nan": (b"ax,ay,az\n1,2,3\nnan,2,3\n", "row 3, column ax: 'nan' is not finite"),
    "missing column": (b"ax,ay\n1,2\n", "missing column"),
    "ragged": (b"ax,ay,az\n1,2,3\n1,2\n", "row 3 has 2 fields"),
    "too few poses": (b"ax,ay,az\n9.8,0,0\n-9.8,0,0\n0,9.8,0\n", "needs at least 9 poses, got 3"),
    "all alike": (b"ax,ay,az\n" + b"0,0,9.8\n0.001,0,9.8\n0,0.001,9.8\n" * 4, "same way"),
    "binary junk": (bytes(range(256)) * 4, "binary content"),
    "reference model without refs": (b"ax,ay,az\n1,2,3\n", "needs columns ref_x,ref_y,ref_z"),
}


@pytest.mark.parametrize("name", sorted(BAD_INPUTS))
def test_bad_input_one_line_nonzero_and_output_untouched(tmp_path, name, capsys):
    content, message = BAD_INPUTS[name]
    (tmp_path / "poses.csv").write_bytes(content)
    output = tmp_path / "cal.yaml"
    save_calibration(Calibration.identity(), output)
    before = output.read_bytes()
    args = ["fit", str(tmp_path / "poses.csv"), "-o", str(output)]
    if name == "reference model without refs":
        args += ["--model", "reference12"]
    assert main(args) != 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("accel-calib: error:"), err
    assert message in err
    assert output.read_bytes() == before


def test_missing_file_and_bad_calibration_in_a_real_process(tmp_path):
    for args, message in [
        (["fit", tmp_path / "absent.csv", "-o", tmp_path / "x.yaml"], "file not found"),
        (["apply", "-c", tmp_path / "absent.yaml", tmp_path / "a.csv", tmp_path / "b.csv"], "not found"),
        (["fit", "--model", "ellipse", "p.csv", "-o", "x"], "invalid choice"),
        (["frobnicate"], "invalid choice"),
    ]:
        run = subprocess.run([*ACCEL_CALIB, *map(str, args)], capture_output=True, text=True, check=False)
        assert run.returncode != 0
        assert "Traceback" not in run.stderr
        assert run.stderr.count("\n") == 1 and message in run.stderr, run.stderr
