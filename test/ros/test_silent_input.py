"""A silent input, as the node reports it (in-process: the diagnostics' values and the log schedule, no
DDS): a silence that lasts is warned at once, then at doubling intervals up to a few minutes (it was every
5-6 s for ever, 44 lines in 4 minutes), and again at once after the input came back and fell silent anew;
before any Imu message arrived, the advice says so instead of which way to turn the sensor."""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticStatus
from hypothesis import given, settings
from hypothesis import strategies as st

from accel_calibration.core.session import CalibrationSession
from accel_calibration.ros.diagnostics import (
    MAX_REMINDER_S,
    SilenceReminders,
    StreamHealth,
    diagnostic_status,
)

IMU, TEMPERATURE = "/uav1/imu/data_raw", "/uav1/imu/temperature"


def silent_since_start(uptime_s, timeout_s=5.0):
    return StreamHealth(IMU, TEMPERATURE, None, None, timeout_s, uptime_s)


def warnings_over(seconds, reminders, health_at, period_s=1.0):
    """(time, line) of every warning the node's 1 Hz diagnostics timer would log."""
    said = []
    for tick in range(int(seconds / period_s) + 1):
        now = tick * period_s
        said += [(now, line) for line in reminders.due(health_at(now).problem_by_input(), now)]
    return said


def test_four_silent_minutes_are_a_handful_of_warnings_at_doubling_intervals():
    said = warnings_over(240.0, SilenceReminders(), silent_since_start)
    assert 3 <= len(said) <= 7, said  # 44 before
    times = [t for t, _ in said]
    gaps = [b - a for a, b in zip(times, times[1:])]
    assert all(later >= 2 * earlier - 1 for earlier, later in zip(gaps, gaps[1:])), gaps
    assert all(IMU in line for _, line in said)


@settings(max_examples=30, deadline=None)
@given(hours=st.floats(0.1, 6.0), timeout_s=st.floats(1.0, 30.0))
def test_a_long_silence_is_reminded_at_most_every_few_minutes_and_never_less_often(hours, timeout_s):
    seconds = hours * 3600.0
    said = warnings_over(seconds, SilenceReminders(), lambda now: silent_since_start(now, timeout_s), period_s=5.0)
    times = [t for t, _ in said]
    gaps = [b - a for a, b in zip(times, times[1:])]
    assert all(gap <= MAX_REMINDER_S + 5.0 for gap in gaps), gaps
    assert len(said) <= 12 + seconds / MAX_REMINDER_S


def test_a_silence_after_the_input_came_back_is_warned_at_once():
    reminders = SilenceReminders()
    silent = silent_since_start(60.0).problem_by_input()
    assert reminders.due(silent, 60.0) and not reminders.due(silent, 61.0)
    assert reminders.due({}, 62.0) == []  # the input came back
    again = StreamHealth(IMU, TEMPERATURE, 6.0, None, 5.0, 80.0).problem_by_input()
    assert len(reminders.due(again, 80.0)) == 1


def status_of(health):
    progress = CalibrationSession().progress()
    return diagnostic_status("accel_calibration: /uav1/accel_calibration", DiagnosticStatus.OK, "waiting", progress,
                             {}, {}, {}, None, "imu0", health, ())


def test_before_any_imu_message_the_advice_says_nothing_has_arrived():
    for uptime_s in (0.5, 30.0):
        status = status_of(silent_since_start(uptime_s))
        values = {kv.key: kv.value for kv in status.values}
        assert values["advice"] == f"waiting for data on {IMU}: no Imu message yet", values["advice"]
        assert "turn" not in status.message, status.message


def test_once_messages_arrive_the_advice_is_which_way_to_turn():
    status = status_of(StreamHealth(IMU, TEMPERATURE, 0.01, None, 5.0, 30.0))
    values = {kv.key: kv.value for kv in status.values}
    assert values["advice"].startswith("turn"), values["advice"]
