"""`--node` names the node whose --params-file blocks apply: a name rcl would refuse (a space, a digit
first, `//`, a trailing `/`, `~`) matches no block the node could ever have, so it is refused in one line,
not taken silently."""
from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from accel_calibration.cli.options import check_node_name
from accel_calibration.core.errors import CalibrationError

from helpers.one_line import assert_one_error_line, run_main

TOKEN = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,10}", fullmatch=True)


@settings(max_examples=50, deadline=None)
@given(namespace=st.lists(TOKEN, max_size=3), name=TOKEN, leading=st.booleans())
def test_valid_node_names_are_taken(namespace, name, leading):
    text = "/".join([*namespace, name])
    check_node_name("/" + text if leading or namespace else text)


@pytest.mark.parametrize("name", ["not a name", "1node", "/uav1//node", "/uav1/node/", "/", "", "~/node",
                                  "/uav1/2fast", "/ns/nö", "node-1", "/uav1/{node}"])
def test_invalid_node_names_are_refused_in_one_line(tmp_path, name):
    with pytest.raises(CalibrationError, match="--node"):
        check_node_name(name)
    recording, params = tmp_path / "imu.csv", tmp_path / "params.yaml"
    recording.write_text("t,ax,ay,az\n0,0,0,9.8\n")
    params.write_text("/**:\n  ros__parameters:\n    min_poses: 12\n")
    for extra in ([], ["--params-file", params]):
        code, err = run_main(["replay", recording, "--node", name, *extra])
        assert_one_error_line(code, err, "--node", "not a ROS node name")
