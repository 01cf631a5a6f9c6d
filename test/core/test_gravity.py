"""WGS84 normal gravity against its published values, and the settings that take a latitude."""
from __future__ import annotations

import math

import pytest

from accel_calibration.core.errors import CalibrationError, SettingsError
from accel_calibration.core.gravity import normal_gravity
from accel_calibration.core.settings import Settings


def test_normal_gravity_is_wgs84s_published_values():
    # NIMA TR8350.2 (WGS84), table 3.4: normal gravity at the equator and at the poles.
    assert normal_gravity(0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert normal_gravity(90.0) == pytest.approx(9.8321849378, abs=1e-10)
    assert normal_gravity(-90.0) == pytest.approx(9.8321849378, abs=1e-10)
    # Between them it rises monotonically with |latitude|, symmetric about the equator.
    values = [normal_gravity(latitude) for latitude in range(0, 91, 5)]
    assert values == sorted(values) and normal_gravity(-30.0) == normal_gravity(30.0)


def test_free_air_correction_is_about_0_3086_mgal_per_metre():
    for latitude in (0.0, 45.0, 90.0):
        ground = normal_gravity(latitude)
        drop = ground - normal_gravity(latitude, 1000.0)
        assert drop == pytest.approx(3.086e-3, rel=2e-3)  # 1 mGal = 1e-5 m/s^2: 308.6 mGal per km
        # second order: 3 h^2 / a^2 against ten times the 1 km drop (which holds a hundredth of it)
        linear = ground - 10 * drop
        expected = ground * 3 * (10_000.0**2 - 10 * 1000.0**2) / 6378137.0**2
        assert normal_gravity(latitude, 10_000.0) - linear == pytest.approx(expected, rel=1e-6)


def test_latitude_out_of_range_is_refused():
    for latitude, height in ((90.5, 0.0), (math.nan, 0.0), (45.0, 1e6)):
        with pytest.raises(CalibrationError, match="must be within"):
            normal_gravity(latitude, height)


def test_settings_take_a_latitude_instead_of_gravity_and_say_so():
    settings = Settings.from_parameters({"latitude_deg": 47.4, "height_m": 500.0})
    assert settings.gravity == normal_gravity(47.4, 500.0)
    assert settings.gravity_source == "WGS84 normal gravity, latitude 47.40 deg, height 500 m"
    assert Settings().gravity_source == "standard" and math.isnan(Settings().latitude_deg)
    assert Settings.from_parameters({"gravity": 9.81}).gravity_source == "given"
    with pytest.raises(SettingsError, match="gravity .* and latitude_deg exclude each other"):
        Settings.from_parameters({"latitude_deg": 47.4, "gravity": 9.81})
    with pytest.raises(SettingsError, match="height_m needs latitude_deg"):
        Settings.from_parameters({"height_m": 500.0})
    with pytest.raises(SettingsError, match="latitude_deg must be within -90..90"):
        Settings.from_parameters({"latitude_deg": 91.0})
