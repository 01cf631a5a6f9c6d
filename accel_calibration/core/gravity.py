"""Local gravity: the WGS84 normal gravity at a geodetic latitude and height above the ellipsoid, and the
words a calibration file keeps for where its g came from.

Somigliana's closed formula on the ellipsoid, gamma = gamma_e (1 + k sin^2 phi) / sqrt(1 - e^2 sin^2 phi),
and WGS84's second-order free-air correction above it,
gamma_h = gamma [1 - 2/a (1 + f + m - 2 f sin^2 phi) h + 3 h^2 / a^2] (NIMA TR8350.2, eq. 4-1 and 4-3).
The normal gravity leaves out local anomalies (tens of mGal, a few ppm of g)."""
from __future__ import annotations

import math

from .errors import CalibrationError
from .units import STANDARD_GRAVITY

EQUATORIAL_GRAVITY = 9.7803253359  # gamma_e, m/s^2
SOMIGLIANA_K = 0.00193185265241
ECCENTRICITY_SQUARED = 0.00669437999013  # e^2
SEMI_MAJOR_AXIS_M = 6378137.0  # a
FLATTENING = 1.0 / 298.257223563  # f
GRAVITY_RATIO = 0.00344978650684  # m = omega^2 a^2 b / GM
LATITUDE_RANGE_DEG = (-90.0, 90.0)
HEIGHT_RANGE_M = (-500.0, 20_000.0)  # the Dead Sea shore to a high-altitude balloon


def normal_gravity(latitude_deg: float, height_m: float = 0.0) -> float:
    """WGS84 normal gravity, m/s^2, at this geodetic latitude (deg) and height above the ellipsoid (m)."""
    low, high = LATITUDE_RANGE_DEG
    if not (math.isfinite(latitude_deg) and low <= latitude_deg <= high):
        raise CalibrationError(f"latitude must be within {low:g}..{high:g} degrees, got {latitude_deg!r}")
    low, high = HEIGHT_RANGE_M
    if not (math.isfinite(height_m) and low <= height_m <= high):
        raise CalibrationError(f"height must be within {low:g}..{high:g} m, got {height_m!r}")
    s2 = math.sin(math.radians(latitude_deg)) ** 2
    gamma = EQUATORIAL_GRAVITY * (1.0 + SOMIGLIANA_K * s2) / math.sqrt(1.0 - ECCENTRICITY_SQUARED * s2)
    a, f = SEMI_MAJOR_AXIS_M, FLATTENING
    return gamma * (1.0 - 2.0 / a * (1.0 + f + GRAVITY_RATIO - 2.0 * f * s2) * height_m
                    + 3.0 * height_m**2 / a**2)


def normal_gravity_source(latitude_deg: float, height_m: float = 0.0) -> str:
    """How a calibration file says its g came from the normal gravity."""
    return f"WGS84 normal gravity, latitude {latitude_deg:.2f} deg, height {height_m:g} m"


def given_gravity_source(gravity: float) -> str:
    """"standard" for 9.80665 m/s^2, else "given" (a number the user gave)."""
    return "standard" if gravity == STANDARD_GRAVITY else "given"
