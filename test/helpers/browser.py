"""A real browser for the tests: Debian's chromium, headless, with a fresh profile and no network of its own
(no background networking, no component updates). Skips where it is missing, fails under CI (CI=true),
where .ci/run installs it."""
from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

from helpers.ci import under_ci

NAMES = ("chromium", "chromium-browser")
TIMEOUT_S = 120.0


def chromium() -> str:
    for name in NAMES:
        found = shutil.which(name)
        if found:
            return found
    reason = "no chromium on PATH (Debian: apt-get install chromium): the page is not checked in a browser"
    if under_ci():
        pytest.fail(f"{reason} (CI=true: the browser must be here)")
    pytest.skip(reason)


def _run(page: Path, *action: str) -> subprocess.CompletedProcess[str]:
    with tempfile.TemporaryDirectory(prefix="accel-calib-chromium-") as profile:
        command = [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                   "--disable-component-update", "--no-first-run", "--disable-sync", "--disable-extensions",
                   f"--user-data-dir={profile}", *action, page.resolve().as_uri()]
        return subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT_S, check=False)


def dom_after_scripts(page: Path) -> str:
    """The page's DOM once its scripts ran (chromium --dump-dom)."""
    done = _run(page, "--dump-dom")
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def screenshot(page: Path, png: Path, size: str = "1000,1400") -> Path:
    done = _run(page, f"--screenshot={png}", f"--window-size={size}")
    assert done.returncode == 0 and png.is_file(), done.stderr[-2000:]
    return png
