"""What starting the command line does before any command runs (bench/bench_startup.py measures its time)."""
from __future__ import annotations

import os
import subprocess
import sys

PROBE = """
import os, sys
before = 'numpy' in sys.modules
import accel_calibration.cli.main
print(before, os.environ.get('OPENBLAS_NUM_THREADS'))
"""


def _probe(**env: str) -> list[str]:
    environment = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")} | env
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, check=True, env=environment)
    return done.stdout.split()


def test_the_cli_asks_for_one_blas_thread_before_numpy_loads():
    # numpy not loaded before the package: the setting reaches OpenBLAS.
    assert _probe() == ["False", "1"]


def test_a_users_own_blas_thread_count_is_kept():
    assert _probe(OPENBLAS_NUM_THREADS="2")[1] == "2"
