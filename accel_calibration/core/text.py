"""A user's text as a message or a record shows it: a string (a frame_id, an expression) echoed in one line
of a log or an error, recognisable and never a screenful; any bytes a file name holds, printable."""
from __future__ import annotations

__all__ = ["QUOTED_CHARACTERS", "printable_text", "quoted"]

QUOTED_CHARACTERS = 60


def quoted(text: str) -> str:
    """`text` as a message quotes it: repr, cut to QUOTED_CHARACTERS with its length said."""
    if len(text) <= QUOTED_CHARACTERS:
        return repr(text)
    return f"{text[:QUOTED_CHARACTERS]!r}... ({len(text)} characters)"


def printable_text(value: str) -> str:
    """Text any database and any terminal takes: an undecodable byte of a file name (a lone surrogate)
    becomes U+FFFD and a NUL '\\0'; everything else is kept."""
    if value.isprintable() or not any(c == "\0" or "\ud800" <= c <= "\udfff" for c in value):
        return value
    return "".join("\\0" if c == "\0" else "\ufffd" if "\ud800" <= c <= "\udfff" else c for c in value)
