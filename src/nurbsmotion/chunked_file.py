"""Files written from text formatted elsewhere (the cycle thread's slack), one system call a
chunk.

A thread that formats a large table in one go holds the interpreter lock throughout, and the
SCHED_FIFO cycle thread that wakes meanwhile waits for it (fieldbus.cycle_slack). So the
daemon formats its job files in the cycle thread's slack, in short steps that each encode a
chunk, and the thread that owns the file writes the chunks here: an unbuffered ``write`` per
chunk, which lets go of the lock during the system call, so the cycle thread never waits for
file I/O nor does any itself. A leaf module (imports nothing of the package).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import BinaryIO, Iterable


def write_all(out: BinaryIO, chunks: Iterable[bytes]) -> int:
    """Write every chunk to the unbuffered ``out`` (``open(path, "wb", buffering=0)``); the
    bytes written."""
    written = 0
    for chunk in chunks:
        view = memoryview(chunk)
        while view:
            n = out.write(view)
            if n is None:  # a non-blocking file that took nothing: regular files never do
                raise BlockingIOError(f"{getattr(out, 'name', 'file')}: wrote nothing")
            view = view[n:]
            written += n
    return written


def write_file(path: str | Path, chunks: Iterable[bytes]) -> Path:
    """``path`` (its folders made) holding the chunks in order; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb", buffering=0) as out:
        write_all(out, chunks)
    return path


def take_text(text: io.StringIO) -> bytes:
    """What ``text`` holds, UTF-8 encoded, and ``text`` emptied for the next chunk."""
    chunk = text.getvalue().encode("utf-8")
    text.seek(0)
    text.truncate(0)
    return chunk
