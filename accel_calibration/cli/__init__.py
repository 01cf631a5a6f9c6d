"""The accel-calib command line: one function per command, each returning an exit code."""
