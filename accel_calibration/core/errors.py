"""The core's one error type. Front ends (CLI, node, replay) catch it and show its message on one line."""


class CalibrationError(ValueError):
    """Bad input to the calibration core, or a calibration file that cannot be used.

    The message says what is wrong and, where it can, what to do about it.
    """
