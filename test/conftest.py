"""Test-session isolation, access to ../shared reference data, and the fixtures tests of several layers share.
The one conftest: the layer folders (core, io, live, bag, ros, cli, package) have none; shared helpers that are
not fixtures live in test/helpers/."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings as hypothesis_settings

from helpers.ci import under_ci
from helpers.ros_domain import claim_ros_domain

# DDS traffic stays on this machine; the domain is claimed per test process in pytest_configure.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("MPLBACKEND", "Agg")

# Property tests explore new examples on every developer run; under CI (CI=true) they run a fixed set
# derived from each test, so a gate never turns red on an example nobody has seen (a failure found
# locally is kept as an @example).
hypothesis_settings.register_profile("ci", derandomize=True, print_blob=True)
if under_ci():
    hypothesis_settings.load_profile("ci")


def pytest_configure(config):
    """Each process that runs tests (the one pytest process, or each pytest-xdist worker: `make test` runs
    `pytest -n 2`) holds a DDS domain of its own for its lifetime, so parallel workers, parallel sessions
    and other ROS graphs never see each other (helpers/ros_domain.py). Set before any test module is
    imported, so before anything initialises rclpy; the node processes a test starts inherit it. An xdist
    controller runs no test and claims none."""
    controller = not hasattr(config, "workerinput") and config.getoption("dist", default="no") != "no"
    if not controller:
        claim_ros_domain()


def pytest_collection_modifyitems(config, items):
    """Under pytest-xdist, the tests over DDS (marked `ros`: 5-30 s each, the longest of the suite) are
    handed out first and the many short ones last, so the workers finish together instead of one waiting
    on the other's last long test. Each worker collects the same order; a plain run keeps the files' order."""
    if hasattr(config, "workerinput"):
        items.sort(key=lambda item: item.get_closest_marker("ros") is None)


REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


def shared_path(relative: str) -> Path:
    """Path of a file under ../shared/data. Skips where ../shared is absent (a user's own clone);
    fails under CI, where it must be present."""
    path = SHARED_DATA / relative
    if not path.exists():
        reason = f"reference data {path} not found (../shared is not beside this clone)"
        if under_ci():
            pytest.fail(reason)
        pytest.skip(reason)
    return path


@pytest.fixture
def shared():
    return shared_path


@pytest.fixture(scope="module")
def ros():
    """rclpy for a module of tests that talk to calibration_node over DDS."""
    import rclpy

    rclpy.init()
    yield
    rclpy.shutdown()


@pytest.fixture
def tester(ros):
    from msg_tools.calibration_client import CalibrationClient

    client = CalibrationClient()
    yield client
    client.destroy()


@pytest.fixture
def node_process():
    """Start calibration_node processes with `start(...)` (NodeProcess arguments); every one is
    stopped at the end whatever the test did."""
    from msg_tools.node_process import NodeProcess

    started = []

    def start(*args, **kwargs):
        node = NodeProcess(*args, **kwargs)
        started.append(node)
        return node

    yield start
    for node in started:
        node.stop()


@pytest.fixture(scope="session")
def postgres():
    """One throwaway PostgreSQL server for the session (helpers/postgres_server.py). Skipped where the server
    binaries are missing; under CI (CI=true) that is a failure instead: the CI machine must have them
    (.ci/run installs them)."""
    from helpers.postgres_server import PostgresServer, PostgresUnavailable

    try:
        server = PostgresServer()
    except PostgresUnavailable as missing:
        if under_ci():
            pytest.fail(f"{missing} (CI=true: PostgreSQL must be here)")
        pytest.skip(str(missing))
    with server:
        yield server


@pytest.fixture
def pg_url(postgres):
    """A fresh database of its own for a test."""
    return postgres.create_database("history")
