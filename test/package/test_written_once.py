"""Each default and rule written once, read from there: the detector's defaults are the detector's
(core/stream/detector_batch.DetectorConfig), the refusal of a change to a setting fixed at start-up is one
text (core/settings.fixed_at_start_up) that the session and the node both give, the sensor axes are
units.AXES, and a setting has one name from the command line to the node parameter (the flag's value is
kept under the parameter's own name: no table translates one into the other)."""
from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from accel_calibration.core.errors import SettingsError
from accel_calibration.core.session import CalibrationSession
from accel_calibration.core.settings import BY_NAME, PARAMETERS, Settings, fixed_at_start_up
from accel_calibration.core.stream.detector_batch import DetectorConfig

PACKAGE = Path(__file__).resolve().parents[2] / "accel_calibration"


def sources() -> dict[str, str]:
    return {str(p.relative_to(PACKAGE)): p.read_text(encoding="utf-8") for p in sorted(PACKAGE.rglob("*.py"))}


def test_the_detectors_parameters_default_to_the_detectors_own_defaults():
    detector = DetectorConfig()
    shared = [p for p in PARAMETERS if p.name.startswith("static.") and hasattr(detector, p.name[len("static."):])
              and getattr(detector, p.name[len("static."):]) is not None]
    assert {p.name for p in shared} >= {"static.window_s", "static.min_hold_s", "static.k_sigma",
                                        "static.max_floor_rise"}
    for parameter in shared:
        assert parameter.default == getattr(detector, parameter.name[len("static."):]), parameter.name
    settings_text = sources()["core/settings.py"]
    for parameter in shared:  # read from the detector's, not written again
        assert not re.search(rf'Parameter\("{re.escape(parameter.name)}", [0-9]', settings_text), parameter.name


def test_every_parameter_is_one_settings_field_by_one_rule():
    fields = list(Settings.__dataclass_fields__)
    assert sorted(fields) == sorted(p.name.replace(".", "_") for p in PARAMETERS)
    assert all(BY_NAME[p.name].field == p.name.replace(".", "_") for p in PARAMETERS)


def test_a_change_to_a_setting_fixed_at_start_up_is_refused_in_one_text_written_once():
    session = CalibrationSession(Settings())
    with pytest.raises(SettingsError) as refused:
        session.update_settings(Settings(max_poses=50))
    assert str(refused.value) == fixed_at_start_up("max_poses")
    said = [name for name, text in sources().items() if "fixed at start-up (read-only)" in text]
    assert said == ["core/settings.py"]


def test_the_sensor_axes_are_written_once():
    written = [name for name, text in sources().items() if re.search(r"""["']xyz["']""", text)]
    assert written == ["core/units.py"]


def settings_flags() -> list[argparse.Action]:
    """The options of every command that stand for a node parameter (their help says `-p NAME:=...`)."""
    from accel_calibration.cli.main import _parser

    parser = _parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return [action for command in commands.choices.values() for action in command._actions
            if action.help and re.search(r"-p [\w.]+:=\.\.\.", action.help)]


def test_every_flag_standing_for_a_parameter_keeps_its_value_under_the_parameters_name():
    flags = settings_flags()
    assert {a.option_strings[0] for a in flags} >= {"--model", "--min-poses", "--window", "--min-hold",
                                                   "--k-sigma", "--temperature-model", "--min-span"}
    for action in flags:
        named = re.search(r"-p ([\w.]+):=", action.help).group(1)
        assert named in BY_NAME, (action.option_strings, named)
        assert action.dest == named, (action.option_strings, action.dest, named)
    import accel_calibration.cli.options as options

    assert not hasattr(options, "FLAG_PARAMETERS")  # no table from flags to parameters


GATE_PARAMETERS = ("min_poses", "max_residual_rms_mg", "max_bias_sigma_mg", "max_scale_sigma_ppm",
                   "max_misalignment_sigma_mrad", "max_bias_mps2", "scale_min", "scale_max")


def test_the_gates_parameters_default_to_the_gates_own_defaults():
    from accel_calibration.core.gates import QualityGates

    assert Settings().quality_gates == QualityGates()
    settings_text = sources()["core/settings.py"]
    for name in GATE_PARAMETERS:  # read from the gates', not written again
        assert not re.search(rf'Parameter\("{name}", [0-9]', settings_text), name
    defaults = [name for name, text in sources().items()
                if re.search(r"max_bias_mps2: float = [0-9]|scale_band: tuple\[float, float\] = \(", text)]
    assert defaults == ["core/plausibility.py"] or defaults == [], defaults


def test_an_axis_gain_outside_its_band_is_judged_in_one_place():
    judged = [name for name, text in sources().items() if 'f"correction gain {' in text]
    assert judged == ["core/plausibility.py"]
    assert sources()["core/plausibility.py"].count('f"correction gain {') == 1


def test_each_detector_parameter_is_the_detectors_setting_of_the_same_name():
    """`static.NAME` is the detector's NAME (no table renames it); only the two noise ceilings, given in mg
    and mrad/s, are converted (the detector knows no unit)."""
    import dataclasses

    from accel_calibration.core.stream.stream_side import detector_config

    detector = {f.name for f in dataclasses.fields(DetectorConfig)}
    static = [p for p in PARAMETERS if p.name.startswith("static.")]
    assert {p.name for p in static if p.name.removeprefix("static.") not in detector} == {
        "static.max_noise_mg", "static.max_gyro_noise_mradps"}
    settings = Settings.from_parameters({"static.window_s": 0.4, "static.min_hold_s": 2.5, "static.k_sigma": 7.0,
                                         "static.max_floor_rise": 2.0, "static.accel_var_threshold": 0.01})
    config = detector_config(settings)
    for parameter in static:
        name = parameter.name.removeprefix("static.")
        if name in detector:
            assert getattr(config, name) == (getattr(settings, parameter.field) or None), name
    assert config.accel_noise_ceiling == pytest.approx(settings.static_max_noise_mg * 9.80665e-3)
