"""--armed-field names a message field, nothing else: a private or special attribute (`__class__`,
`__init__.__globals__`, `_x`) would read Python's internals, truthy for every message, and mark the whole
recording as armed; it is refused in one line, and so is an expression of any length, quoted short."""
from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from accel_calibration.bag.flight_sources import FlightStateError, field_test

from helpers.one_line import assert_one_error_line, run_main

IDENTIFIER = st.from_regex(r"[A-Za-z][A-Za-z0-9_]{0,8}", fullmatch=True)


@settings(max_examples=40, deadline=None)
@given(before=st.lists(IDENTIFIER, max_size=2), private=st.from_regex(r"_[A-Za-z0-9_]{0,8}", fullmatch=True),
       after=st.lists(IDENTIFIER, max_size=2), comparison=st.sampled_from(["", "not ", " == 2"]))
def test_a_field_path_with_an_underscore_led_part_is_refused(before, private, after, comparison):
    path = ".".join([*before, private, *after])
    expression = f"not {path}" if comparison == "not " else path + comparison
    with pytest.raises(FlightStateError, match="underscore"):
        field_test(expression)


@pytest.mark.parametrize("field", ["__class__", "__init__.__globals__", "header.__class__", "_private"])
def test_replay_refuses_a_dunder_armed_field_in_one_line(tmp_path, field):
    recording = tmp_path / "imu.csv"
    recording.write_text("t,ax,ay,az\n0,0,0,9.8\n")
    code, err = run_main(["replay", recording, "--armed-topic", "/armed", "--armed-field", field])
    assert_one_error_line(code, err, "--armed-field", "underscore")


def test_a_huge_expression_is_not_repeated_in_the_error(tmp_path):
    recording = tmp_path / "imu.csv"
    recording.write_text("t,ax,ay,az\n0,0,0,9.8\n")
    expression = "armed == = " + "x" * 120_000
    code, err = run_main(["replay", recording, "--armed-topic", "/armed", "--armed-field", expression])
    assert_one_error_line(code, err, "--armed-field", f"{len(expression)} characters")
    assert len(err) < 400, len(err)


def test_plain_fields_still_work():
    class Message:
        armed, arming_state = True, 2
        header = type("Header", (), {"frame_id": "x"})()

    assert field_test("armed")(Message()) and field_test("arming_state == 2")(Message())
    assert not field_test("header.frame_id == 3")(Message())
