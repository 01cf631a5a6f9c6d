"""Errors: one base for the package, one type per layer. Front ends (CLI, node, replay) catch
`AccelCalibrationError` and show its message on one line; the message says what to do."""


class AccelCalibrationError(Exception):
    """Base of every error this package raises on purpose (bad input, bad files, bad settings)."""


class CalibrationError(AccelCalibrationError, ValueError):
    """core: bad input to the calibration core, or a calibration that cannot be used."""


class DeprecatedInputWarning(UserWarning):
    """An input in a form an older version wrote or took, still read as it meant: the front ends say it in
    one line (the CLI: 'accel-calib: warning: ...'), with what to write instead."""


class SettingsError(CalibrationError):
    """core: a setting (node parameter, params file entry, CLI flag) out of type or range; the message
    names the parameter as the user typed it."""
