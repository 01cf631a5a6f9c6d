"""One correction everywhere: `accel-calib apply` and the report's residuals correct each row as the node
corrects a message (core/correction.Correction at the row's temperature), bit for bit, on any CPU: the
arithmetic is elementwise, no BLAS. Calibration.apply (a matrix product) is the fit's own model, not what
a user's numbers go through."""
from __future__ import annotations

import csv

import numpy as np

from accel_calibration import Calibration, save_calibration
from accel_calibration.cli.main import main
from accel_calibration.core.correction import TEMPERATURE_DECIMALS, Correction, correct_rows
from accel_calibration.core.temperature_models import TemperatureModel

MATRIX = np.array([[1.012, 0.0, 0.0], [0.0031, 0.987, 0.0], [-0.0022, 0.0043, 1.006]])
BIAS = np.array([0.31, -0.22, 0.27])


def calibration_with_drift() -> Calibration:
    drift = TemperatureModel("polynomial", 25.0, (5.0, 45.0), bias_coefficients=np.array([[2e-3, -1e-3, 1.5e-3]]),
                             scale_coefficients=np.array([[1e-4, -8e-5, 1.2e-4]]))
    return Calibration(bias=BIAS, matrix=MATRIX, model="sphere9", temperature=drift, reference_temperature_degc=25.0)


def node_corrects(calibration: Calibration, row: np.ndarray, temperature_degc: float | None) -> tuple[float, ...]:
    """One message as the node corrects it: the Correction at the (rounded) temperature, on floats."""
    at = None if temperature_degc is None else round(temperature_degc, TEMPERATURE_DECIMALS)
    correction = Correction.build(calibration, at)
    assert correction is not None
    return correction.apply(*(float(v) for v in row))


def test_apply_writes_what_the_node_would_publish_for_each_row_bit_for_bit(tmp_path):
    rng = np.random.default_rng(3)
    calibration = calibration_with_drift()
    save_calibration(calibration, tmp_path / "cal.yaml")
    raw = rng.normal(0.0, 6.0, (200, 3))
    temperatures = rng.uniform(5.0, 45.0, 200)
    with open(tmp_path / "in.csv", "w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["t", "ax", "ay", "az", "temperature"])
        for i, (row, temperature) in enumerate(zip(raw, temperatures)):
            writer.writerow([i, *map(repr, row.tolist()), repr(float(temperature))])
    assert main(["apply", "-c", str(tmp_path / "cal.yaml"), str(tmp_path / "in.csv"), str(tmp_path / "out.csv")]) == 0
    with open(tmp_path / "out.csv", newline="") as stream:
        written = [tuple(float(r[k]) for k in ("ax", "ay", "az")) for r in csv.DictReader(stream)]
    expected = [node_corrects(calibration, row, float(t)) for row, t in zip(raw, temperatures)]
    assert written == expected


def test_rows_alone_and_together_are_corrected_to_the_same_bits():
    rng = np.random.default_rng(4)
    calibration = calibration_with_drift()
    raw = rng.normal(0.0, 6.0, (64, 3))
    temperatures = np.round(rng.uniform(5.0, 45.0, 64), 1)
    together = correct_rows(calibration, raw, temperatures)
    alone = np.array([correct_rows(calibration, raw[i:i + 1], temperatures[i:i + 1])[0] for i in range(len(raw))])
    np.testing.assert_array_equal(together, alone)
    # Without temperatures, at the reference temperature, as the node before any reading.
    np.testing.assert_array_equal(correct_rows(calibration, raw[:1])[0], node_corrects(calibration, raw[0], None))
