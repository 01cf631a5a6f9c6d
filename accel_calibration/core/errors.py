"""Errors: one base for the package, one type per layer. Front ends (CLI, node, replay) catch
`AccelCalibrationError` and show its message on one line; the message says what to do."""


class AccelCalibrationError(Exception):
    """Base of every error this package raises on purpose (bad input, bad files, bad settings)."""


class CalibrationError(AccelCalibrationError, ValueError):
    """core: bad input to the calibration core, or a calibration that cannot be used."""


class SettingsError(CalibrationError):
    """core: a setting (node parameter, params file entry, CLI flag) out of type or range; the message
    names the parameter as the user typed it."""
