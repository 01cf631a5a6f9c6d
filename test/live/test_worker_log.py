"""The worker's log lines reach the node over the pipe: throttled per call site, and debug lines only when
the node shows them (each line is pickled and sent: at info, the debug ones would be sent for nothing)."""
from __future__ import annotations

from accel_calibration.live.worker_loop import _PipeLog
from accel_calibration.live.worker_protocol import LogLevel, LogLine


class Pipe:
    def __init__(self):
        self.sent = []

    def send(self, message):
        self.sent.append(message)


def test_debug_lines_are_sent_only_when_the_node_shows_them():
    for debug_logged, expected in ((False, [LogLine(LogLevel.INFO, "kept")]),
                                   (True, [LogLine(LogLevel.DEBUG, "detail"), LogLine(LogLevel.INFO, "kept")])):
        pipe = Pipe()
        log = _PipeLog(pipe, debug_logged)
        log.debug("detail")
        log.info("kept")
        assert pipe.sent == expected


def test_a_throttled_line_is_sent_once_per_call_site_and_period():
    pipe = Pipe()
    log = _PipeLog(pipe)
    for _ in range(100):
        log.warning("flood", throttle_duration_sec=5.0)
    log.warning("another site", throttle_duration_sec=5.0)
    assert pipe.sent == [LogLine(LogLevel.WARNING, "flood"), LogLine(LogLevel.WARNING, "another site")]
