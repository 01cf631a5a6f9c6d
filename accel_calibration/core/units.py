"""Units: standard gravity and the milli-g, defined once for the package.

And: is this stream in m/s^2? A driver publishing g (|a| ~ 1) or raw counts (|a| ~ 16384) would be
fitted into nonsense (a 'scale' of 9.8 or 6e-4); say so instead. Used on the poses' magnitudes,
which at rest are |M^-1 g + b|: within a few percent of g for any plausible MEMS part."""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

STANDARD_GRAVITY = 9.80665  # m/s^2, by definition (CGPM 1901): 1 g
MG = STANDARD_GRAVITY * 1e-3  # 1 mg in m/s^2
AXES = "xyz"  # the sensor axes, in the order of every vector's components


def units_problem(accel_mps2: ArrayLike, gravity: float) -> str | None:
    """"units: " and what looks wrong with the stream's units, None when they are m/s^2."""
    text = units_text(accel_mps2, gravity)
    return None if text is None else "units: " + text


def units_text(accel_mps2: ArrayLike, gravity: float) -> str | None:
    """What looks wrong with the stream's units (None when they are m/s^2), said without a prefix."""
    magnitudes = np.linalg.norm(np.asarray(accel_mps2, dtype=float).reshape(-1, 3), axis=1)
    if len(magnitudes) == 0:
        return None
    typical = float(np.median(magnitudes))
    if 0.7 * gravity <= typical <= 1.3 * gravity:
        return None
    if 0.7 <= typical <= 1.3:
        return (f"still poses read |a| = {typical:.3f}, which looks like g, not m/s^2 "
                f"(expected ~{gravity:.2f}): convert the stream (x {STANDARD_GRAVITY}) before calibrating")
    if typical > 30 * gravity:
        return (f"still poses read |a| = {typical:.0f}, which looks like raw sensor counts, not m/s^2: "
                "scale the driver's output to m/s^2 before calibrating")
    return (f"still poses read |a| = {typical:.3f}, expected ~{gravity:.2f} m/s^2: "
            "check the driver's units and scaling")
