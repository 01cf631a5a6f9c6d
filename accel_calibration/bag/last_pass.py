"""The last log's pass over a flight log, kept for the asks that follow it (ulog_pass.py, dataflash_pass.py):
a fleet task reads its logs one after another, and asks of each, IMU after IMU, what one walk of the file
gives. A pass is known by the file's resolved path, size and modification time: a log rewritten in place is
read again."""
from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, Generic, Protocol, TypeVar


class Pass(Protocol):
    identity: tuple[str, int, int]
    margin_s: float


P = TypeVar("P", bound=Pass)


def identity(path: str | os.PathLike[str]) -> tuple[str, int, int]:
    stat = os.stat(path)
    return str(Path(path).resolve()), stat.st_size, stat.st_mtime_ns


class LastPass(Generic[P]):
    """The last pass `read(path, margin_s, progress)` made, kept until another log is asked for."""

    def __init__(self, read: Callable[[Path, float, Any], P]) -> None:
        self._read = read
        self._kept: P | None = None

    def cached(self, path: str | os.PathLike[str]) -> P | None:
        """The pass of this file kept from an earlier ask (whatever its margin), None when there is none."""
        try:
            known = identity(path)
        except OSError:
            return None
        return self._kept if self._kept is not None and self._kept.identity == known else None

    def get(self, path: str | os.PathLike[str], margin_s: float, progress: Any = None) -> P:
        """The pass of this file for this margin: kept from the last ask, or read now (replacing it)."""
        found = self.cached(path)
        if found is not None and found.margin_s == margin_s:
            return found
        self._kept = self._read(Path(path), margin_s, progress)
        return self._kept

    def forget(self) -> None:
        """Drop the kept pass (the next ask reads its log again)."""
        self._kept = None
