"""Two nodes of one fully qualified name share services, parameters and, by default, the calibration
file: each says so (a WARN in its log and on /diagnostics), found from the ROS graph after discovery,
never on the stream's path. The rule in-process; the wiring over DDS."""
from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from accel_calibration.ros.diagnostics import namesake_problem

TOKEN = st.from_regex(r"[a-z][a-z0-9_]{0,6}", fullmatch=True)


@given(namespace=st.lists(TOKEN, max_size=2).map(lambda parts: "/" + "/".join(parts)), name=TOKEN,
       others=st.lists(st.tuples(TOKEN, TOKEN.map(lambda t: "/" + t)), max_size=5))
def test_only_the_same_fully_qualified_name_counts(namespace, name, others):
    fqn = f"{namespace.rstrip('/')}/{name}"
    graph = [(name, namespace), *[(n, ns) for n, ns in others if f"{ns}/{n}" != fqn]]
    assert namesake_problem(fqn, graph) is None
    problem = namesake_problem(fqn, [*graph, (name, namespace)])
    assert problem is not None and problem.startswith(f"2 nodes are named {fqn}:") and "\n" not in problem


@pytest.mark.ros
def test_two_nodes_of_one_name_each_warn(tmp_path, tester, node_process):
    first = node_process(tmp_path / "first.yaml")
    second = node_process(tmp_path / "second.yaml")
    said = "2 nodes are named /accel_calibration"
    assert tester.spin_until(lambda: said in first.log() and said in second.log(), 30), (first.log(), second.log())
    assert tester.spin_until(lambda: tester.diagnostics and said in tester.diagnostics[-1].get("message", ""), 10), \
        tester.diagnostics[-1:] if tester.diagnostics else "no diagnostics"


@given(others=st.lists(TOKEN.map(lambda t: "/uav1/" + t), max_size=3, unique=True))
def test_another_node_offering_the_calibrate_service_is_one_line(others):
    from accel_calibration.ros.diagnostics import service_twins_problem

    problem = service_twins_problem("/uav1/calibrate", others)
    if not others:
        assert problem is None
        return
    assert problem.startswith(f"{len(others) + 1} nodes offer /uav1/calibrate") and "\n" not in problem
    assert all(other in problem for other in others)


@pytest.mark.ros
def test_two_nodes_of_other_names_in_one_namespace_each_warn(tmp_path, tester, node_process):
    """Finding: two nodes in one namespace both answered one /calibrate, silently (each offers `calibrate`
    in the namespace, whatever its own name)."""
    first = node_process(tmp_path / "first.yaml")
    second = node_process(tmp_path / "second.yaml", ros_args=["-r", "__node:=accel_calibration_b"])
    said = "2 nodes offer /calibrate"
    assert tester.spin_until(lambda: said in first.log() and said in second.log(), 30), (first.log(), second.log())
    assert "/accel_calibration_b" in first.log() and "2 nodes are named" not in first.log()
    assert tester.spin_until(lambda: any(said in d.get("message", "") and d["level"] == b"\x01"
                                         for d in tester.diagnostics[-4:]), 10), tester.diagnostics[-2:]
