"""A Python module the install left out reads as what to install, never as a damaged recording (a
rosdep-only ROS install has none of rosbags, lz4, pyulog, pyarrow: they have no rosdep key)."""
from __future__ import annotations

import importlib.abc
import sys

import numpy as np
import pytest

from accel_calibration.cli.main import main
from msg_tools.bag_writer import write_session_bag
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

START_NS = 1_700_000_000 * 10**9


class _Hidden(importlib.abc.MetaPathFinder):
    """Makes `import name` (and its submodules) fail as on an install without it."""

    def __init__(self, name: str):
        self.name = name

    def find_spec(self, fullname, path=None, target=None):
        if fullname == self.name or fullname.startswith(self.name + "."):
            raise ModuleNotFoundError(f"No module named '{fullname}'", name=fullname)
        return None


@pytest.fixture
def hide(monkeypatch):
    """hide("rosbags"): the module and its submodules are not installed for the rest of the test."""

    def hide_module(name: str) -> None:
        for loaded in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
            monkeypatch.delitem(sys.modules, loaded)
        monkeypatch.setattr(sys, "meta_path", [_Hidden(name), *sys.meta_path])

    return hide_module


@pytest.fixture(scope="module")
def samples():
    rng = np.random.default_rng(3)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    return SyntheticImu(errors, spread_orientations(10, rng), dwell_s=1.0, move_s=0.5, rate_hz=100.0, seed=3).samples()


@pytest.mark.parametrize(("storage", "compression", "module", "install"), [
    ("sqlite3", "", "rosbags", "pip install 'rosbags'"),
    ("mcap", "", "rosbags", "pip install 'rosbags'"),
    ("mcap", "lz4", "lz4", "pip install 'lz4'"),
])
def test_replay_without_a_module_says_what_to_install(tmp_path, capsys, hide, samples, storage, compression,
                                                      module, install):
    bag = tmp_path / "session"
    write_session_bag(bag, samples, start_ns=START_NS, storage=storage, chunk_compression=compression)
    hide(module)
    assert main(["replay", str(bag)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "damaged" not in err and f"'{module}'" in err and "not installed" in err and install in err, err
    assert "pip install -r requirements-ros.txt" in err, err


def test_replay_of_a_csv_stream_without_pyarrow(tmp_path, capsys, hide, samples):
    path = tmp_path / "samples.csv"
    rows = ["t,ax,ay,az"] + [f"{i * 0.01:.2f},{a[0]:.6f},{a[1]:.6f},{a[2]:.6f}"
                             for i, a in enumerate(samples.accel_raw[:50])]
    path.write_text("\n".join(rows) + "\n")
    hide("pyarrow")
    assert main(["replay", str(path)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "damaged" not in err, err
    assert "'pyarrow' is not installed: pip install 'pyarrow'" in err, err


def test_replay_of_a_ulog_without_pyulog(shared, capsys, hide):
    path = shared("real/px4_ulog/sample.ulg")
    hide("pyulog")
    assert main(["replay", str(path)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "damaged" not in err, err
    assert "'pyulog' is not installed: pip install 'pyulog'" in err, err


def test_history_without_sqlalchemy(tmp_path, capsys, hide):
    history = tmp_path / "history.sqlite"
    history.write_bytes(b"")
    hide("sqlalchemy")
    assert main(["history", "--history", str(history)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "'sqlalchemy' is not installed: pip install 'SQLAlchemy>=2'" in err, err


def test_a_missing_module_of_our_own_is_a_bug_not_an_install(hide, tmp_path):
    """Our own module missing is not papered over as an install to fix."""
    hide("accel_calibration.bag.replay")
    with pytest.raises(ModuleNotFoundError):
        main(["replay", str(tmp_path / "session")])
