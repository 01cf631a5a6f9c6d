"""Text as a message quotes it: a user's string (a frame_id, an expression) echoed in one line of a log or
an error, recognisable and never a screenful."""
from __future__ import annotations

__all__ = ["QUOTED_CHARACTERS", "quoted"]

QUOTED_CHARACTERS = 60


def quoted(text: str) -> str:
    """`text` as a message quotes it: repr, cut to QUOTED_CHARACTERS with its length said."""
    if len(text) <= QUOTED_CHARACTERS:
        return repr(text)
    return f"{text[:QUOTED_CHARACTERS]!r}... ({len(text)} characters)"
