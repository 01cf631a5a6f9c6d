"""The one thing the readers ask of a progress bar (a tqdm bar has it): count work done."""
from __future__ import annotations

from typing import Protocol


class ProgressBar(Protocol):
    def update(self, n: int = 1) -> object: ...


class ClosableProgressBar(ProgressBar, Protocol):
    def close(self) -> object: ...
