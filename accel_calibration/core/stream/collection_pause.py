"""Why collection is paused: the armed input, calibration/pause, ... Collection resumes when no reason is
left. The stream marks each sample with `collecting` as it comes: a paused sample drops the still interval
in progress (it may hold the take-off), so nothing of a flight is ever a pose, and the noise floor never
sees it. The reasons are a frozenset replaced whole: any thread reads them without a lock."""
from __future__ import annotations

__all__ = ["CollectionPause"]


class CollectionPause:
    def __init__(self) -> None:
        self._reasons: frozenset[str] = frozenset()

    @property
    def collecting(self) -> bool:
        """False while collection is paused for any reason (the stream is still screened and corrected)."""
        return not self._reasons

    @property
    def reasons(self) -> tuple[str, ...]:
        return tuple(sorted(self._reasons))

    def set_collecting(self, collecting: bool, reason: str) -> None:
        """Pause (False) or resume (True) collection for `reason`."""
        self._reasons = self._reasons - {reason} if collecting else self._reasons | {reason}
