"""accel-calib check says only what the poses can see: from poses all near level, a z bias step is named as
the combination of z terms the poses observe ('bias z or scale z moved (these poses cannot tell which)'),
with the orientation that would part them, and never put on the x and y terms."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from accel_calibration.cli.main import main
from accel_calibration.core.calibration import Calibration
from accel_calibration.core.units import MG
from accel_calibration.io.calibration_file import save_calibration
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, rotation_with_up

from helpers.prior_sessions import near_level


def write_csv(path, s) -> None:
    columns = np.column_stack([s.accel_raw, s.gyro_raw, s.temperature_degc])
    rows = [f"{t},{','.join(repr(float(v)) for v in row)}" for t, row in zip(s.t_ns, columns)]
    path.write_text("t_ns,ax,ay,az,gx,gy,gz,temperature\n" + "\n".join(rows) + "\n")


@pytest.mark.parametrize("degrees", [3.0, 30.0])
def test_a_z_bias_step_seen_from_level_poses_names_what_they_cannot_tell_apart(tmp_path, capsys, degrees):
    """Poses all within a few degrees of z up (or 30): a 5 mg z bias step was 'scale x changed by +55 %,
    scale y +44 %' (or 'bias x -15.8 mg'), exit 3. Exit 3 still, naming only what the poses can see."""
    errors = SensorErrors.mpu6050_like(np.random.default_rng(5), noise_mps2=0.02)
    save_calibration(Calibration(bias=errors.bias_mps2, matrix=errors.matrix, bias_sigma=np.full(3, 0.1 * MG),
                                 matrix_sigma=np.where(np.tril(np.ones((3, 3))) > 0, 1e-4, 0.0)),
                     str(tmp_path / "cal.yaml"))
    moved = dataclasses.replace(errors, bias_mps2=errors.bias_mps2 + np.array([0.0, 0.0, 5 * MG]))
    rng = np.random.default_rng(14)
    # The first dwell is the detector's warm-up: it learns the noise floor there.
    rotations = [rotation_with_up([0.0, 0.0, 1.0])] + [rotation_with_up(d) for d in near_level(10, degrees, rng)]
    write_csv(tmp_path / "level.csv",
              SyntheticImu(moved, rotations, dwell_s=2.5, move_s=0.8, rate_hz=100.0, seed=14).samples())
    assert main(["check", str(tmp_path / "cal.yaml"), str(tmp_path / "level.csv")]) == 3
    verdict = capsys.readouterr().out.splitlines()[0]
    assert "bias z or scale z moved (these poses cannot tell which) by +" in verdict, verdict
    assert "turn z down" in verdict, verdict
    assert not any(name in verdict for name in ("scale x", "scale y", "bias x", "bias y")), verdict
    change_mg = float(verdict.split("tell which) by ")[1].split(" mg")[0])
    assert abs(change_mg - 5.0) < 1.0, verdict
