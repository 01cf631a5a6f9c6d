"""Whether the tests run under CI, read one way everywhere (CI=1, true or yes)."""
from __future__ import annotations

import os


def under_ci() -> bool:
    return os.environ.get("CI", "").lower() in ("1", "true", "yes")
