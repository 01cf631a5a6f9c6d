"""Accuracy of the temperature models on a simulated drifting sensor (issue 4's figure): ~1 mg/degC of
bias drift with curvature and ~1e-4/degC of scale drift, poses over -20..60 degC, errors at 400 fresh
orientations and temperatures. Also the autopilots' bias-only choice and no compensation, same run."""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))

from test_temperature import poses, rms_error_mg  # noqa: E402

from accel_calibration import MG, fit  # noqa: E402
from accel_calibration.core.temperature_models import TemperatureOptions  # noqa: E402


def main() -> int:
    rows = []
    for seed in range(5):
        rng = np.random.default_rng(seed)
        temps = np.concatenate([rng.uniform(24.7, 25.3, 24)]
                               + [rng.uniform(lo, lo + 10, 20) for lo in range(-20, 60, 10)])
        raw, _ = poses(rng, temps)
        fresh_temps = rng.uniform(-18, 58, 400)
        fresh_raw, fresh_true = poses(rng, fresh_temps, noise_mg=0.0)
        row = {}
        for label, kind, options in [
            ("polynomial (bias 2, scale 1)", "polynomial", None),
            ("segmented (seed, 10 degC)", "segmented", TemperatureOptions(model="segmented", reference_degc=25.0)),
            ("bias-only polynomial (autopilots)", "polynomial", TemperatureOptions(bias_order=3, scale_order=0)),
        ]:
            result = fit(raw, temperature_degc=temps, temperature_model=kind, temperature_options=options)
            row[label] = (rms_error_mg(result.calibration, fresh_raw, fresh_true, fresh_temps) if result.success
                          else float("nan"))
        blind = fit(raw).calibration
        row["no temperature model"] = float(np.sqrt(np.mean(np.sum((blind.apply(fresh_raw) - fresh_true) ** 2,
                                                                  axis=1)))) / MG
        rows.append(row)
    print("rms error at fresh orientations and temperatures, mg (5 simulated sessions of the drifting sensor; "
          "targets: polynomial <= 1, "
          "segmented <= 5, uncompensated > 50 over the span):")
    for label in rows[0]:
        values = [r[label] for r in rows]
        print(f"  {label:36s} median {np.median(values):7.2f}   worst {np.max(values):7.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
