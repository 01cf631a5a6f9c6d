"""Test-session isolation, access to ../shared reference data, and the fixtures tests of several layers share.
The one conftest: the layer folders (core, io, bag, ros, cli, package) have none; shared helpers that are
not fixtures live in test/helpers/."""
from __future__ import annotations

import itertools
import os
from pathlib import Path

import pytest
from hypothesis import settings as hypothesis_settings

from helpers.ci import under_ci

# Each test session gets its own DDS domain and stays on this machine, so parallel sessions and
# other ROS graphs never see each other. Set before anything initialises rclpy.
os.environ.setdefault("ROS_DOMAIN_ID", str(10 + os.getpid() % 90))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("MPLBACKEND", "Agg")

# Property tests explore new examples on every developer run; under CI (CI=true) they run a fixed set
# derived from each test, so a gate never turns red on an example nobody has seen (a failure found
# locally is kept as an @example).
hypothesis_settings.register_profile("ci", derandomize=True, print_blob=True)
if under_ci():
    hypothesis_settings.load_profile("ci")

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


_database_names = itertools.count()


@pytest.fixture
def pg_url(postgres):
    """A fresh database of its own for a test."""
    return postgres.create_database(f"history{next(_database_names)}")
