"""`fleet` on flights recorded as rosbag2 (mcap, sqlite3) with two Imu topics, mavros's /mavros/state and PX4's
/fmu/out/estimator_sensor_bias: each bag's row (its --imu-topic, against --calibration) carries in flight the
agreement with the bag's other Imu topic and the filter's settled bias, as JSON in the history; `history`
then follows them over flights."""
from __future__ import annotations

import json

import numpy as np

from accel_calibration.cli.main import main
from accel_calibration.core.calibration import Calibration
from accel_calibration.io.calibration_file import calibration_to_yaml
from accel_calibration.io.history import open_history
from msg_tools.synthetic_imu import SensorErrors

from helpers.flight_bags import write_flight_bag
from helpers.flight_logs import ALL_DEVICES, MG, FilterBias, fly, sensors

OFF_MG = 5.0
FILTER_BIAS = FilterBias(np.array([2.0, -1.0, 4.0]) * MG, np.array([1e-3, 0.0, -5e-4]))


def in_force(truth: SensorErrors) -> Calibration:
    return Calibration(bias=np.array(truth.bias_mps2, float), matrix=np.array(truth.matrix, float), model="six")


def write_bags(root, truths):
    """uavA: three flights, /imu0 raw (replayed against its calibration given), /imu1 recorded corrected; in
    the third /imu0's raw z bias 5 mg up; the filter's bias in the first two."""
    (root / "uavA").mkdir(parents=True)
    for i, storage in enumerate(("mcap", "sqlite3", "mcap")):
        first = truths[0] if i < 2 else SensorErrors(bias_mps2=truths[0].bias_mps2 + [0.0, 0.0, OFF_MG * MG],
                                                     matrix=truths[0].matrix)
        flight = fly([first, truths[1]], 110 + i)
        streams = {"/imu0": flight.raw[0], "/imu1": in_force(truths[1]).apply(flight.raw[1])}
        name = f"flight_{i}" + (".mcap" if storage == "mcap" else "")
        write_flight_bag(root / "uavA" / name, flight, streams, storage,
                         estimator=(FILTER_BIAS, ALL_DEVICES[0]) if i < 2 else None, seed=i)


def test_fleet_rows_of_bags_carry_the_agreement_and_the_filters_bias(tmp_path, capsys):
    truths = sensors(111)
    write_bags(tmp_path / "bags", truths)
    calibration = tmp_path / "imu0.yaml"
    calibration.write_text(calibration_to_yaml(in_force(truths[0])))
    target = str(tmp_path / "fleet.sqlite")
    assert main(["fleet", str(tmp_path / "bags"), "--history", target, "--workers", "1", "--imu-topic", "/imu0",
                 "--calibration", str(calibration)]) == 1  # flights: refused as calibrations
    out = capsys.readouterr().out
    assert ("flight evidence: 3 IMU rows, 3 with evidence from the still moments on the ground, 0 without; in "
            "flight, 2 with the filter's settled bias, 3 with their agreement with their siblings") in out, out
    with open_history(target) as history:
        rows = sorted(history.evidence(), key=lambda r: r.path)
    assert [r.status for r in rows] == ["evidence"] * 3
    for i, row in enumerate(rows):
        estimator, agreement = json.loads(row.estimator), json.loads(row.agreement)
        expected = OFF_MG * truths[0].matrix[2, 2] if i == 2 else 0.0
        assert agreement["against"] == "/imu1" and abs(agreement["accel"][2] / MG - expected) < 0.3, agreement
        assert agreement["in_force"].startswith("/imu0 ") and agreement["in_force"].endswith(
            "imu0.yaml (calibration file); its siblings as recorded")
        if i < 2:
            assert np.all(np.abs(np.array(estimator["accel"]) - FILTER_BIAS.accel_mps2) < 0.1 * MG), estimator
        else:
            assert "records no estimator_sensor_bias" in estimator["reason"]
    assert main(["history", "--history", target]) == 1  # three flights: cannot tell
    out = capsys.readouterr().out
    assert ": agreement with its siblings: cannot tell: " in out and ": the filter's bias: cannot tell: " in out
