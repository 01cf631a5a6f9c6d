"""What a third-party reader prints, kept off the terminal and handed back: pymavlink prints with print()
(to sys.stdout / sys.stderr) and, in its C indexer (dfindexer), with fprintf(stderr) on the process's file
descriptor 2, below Python. Both levels are caught: Python's streams are swapped, and descriptors 1 and 2
point at a temporary file while the block runs."""
from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass

KEPT_CHARS = 1 << 16  # what is kept of the text to quote from; the lines are counted whole


@dataclass
class Captured:
    text: str = ""  # the start of what was printed (Python's, then the descriptors')
    lines: int = 0  # every line printed



def _flush_c_stdio() -> None:
    """C's buffered stdout before the descriptors move back (stderr is unbuffered)."""
    try:
        import ctypes

        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):  # no C library to ask: nothing buffered by it either
        pass


@contextlib.contextmanager
def captured_output() -> Iterator[Captured]:
    captured = Captured()
    python_text = io.StringIO()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    with tempfile.TemporaryFile() as sink:
        saved: list[tuple[int, int]] = []
        try:
            for fd in (1, 2):
                with contextlib.suppress(OSError):  # a descriptor not open: nothing can print there
                    saved.append((fd, os.dup(fd)))
                    os.dup2(sink.fileno(), fd)
            with contextlib.redirect_stdout(python_text), contextlib.redirect_stderr(python_text):
                yield captured
        finally:
            _flush_c_stdio()
            for fd, copy in saved:
                os.dup2(copy, fd)
                os.close(copy)
            sink.seek(0)
            head = sink.read(KEPT_CHARS)
            lines = head.count(b"\n")
            while block := sink.read(1 << 20):
                lines += block.count(b"\n")
            text = python_text.getvalue()
            captured.text = (text + head.decode("utf-8", errors="replace"))[:KEPT_CHARS]
            captured.lines = text.count("\n") + lines


# What pymavlink says when it skips bytes it cannot take for a record (its Python reader and its C indexer).
DAMAGE_MARKERS = ("bad header", "Skipped", "Failed to parse", "bad msg", "unknown msg type")


def damage_said(chatter: Captured) -> str | None:
    """One line on the damage pymavlink reported while reading, or None when it reported none."""
    lines = [line for line in chatter.text.splitlines() if line.startswith(DAMAGE_MARKERS)]
    if not lines:
        return None
    return (f"damaged DataFlash log: pymavlink printed {chatter.lines} lines on bytes it could not read as records "
            f"(first: {lines[0][:60]}); its FMT records may not match its data")
