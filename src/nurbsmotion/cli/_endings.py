"""How a command ends when its user or its reader stops it: Ctrl-C and a closed output pipe
end quietly with the exit code a shell gives any command ended by that signal.

- Ctrl-C (SIGINT): one line ``nurbsmotion CMD: interrupted`` and exit code 130 = 128 + 2.
- The reader of stdout left (``nurbsmotion jobs | head -1``): nothing more is written and
  the exit code is 141 = 128 + 13, what the shell reports for ``cat``, ``grep`` or ``git``
  killed by SIGPIPE there (Python ignores SIGPIPE and raises BrokenPipeError instead).
"""

from __future__ import annotations

import os
import select
import sys
from typing import TextIO

EXIT_INTERRUPTED = 130  # 128 + SIGINT
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE


def reader_gone(stream: TextIO) -> bool:
    """Whether ``stream`` is a pipe or socket whose reading end is closed (poll says POLLERR
    or POLLHUP on its write end), so a BrokenPipeError came from it and not from elsewhere."""
    try:
        poller = select.poll()
        poller.register(stream.fileno(), select.POLLOUT)
        return any(events & (select.POLLERR | select.POLLHUP) for _, events in poller.poll(0))
    except (OSError, ValueError):  # closed or not a file: nothing more can be written to it anyway
        return True


def silence(stream: TextIO) -> None:
    """Point ``stream``'s descriptor at /dev/null, so what it still buffers (flushed when the
    interpreter ends) goes nowhere instead of raising BrokenPipeError again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, stream.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass


def say(line: str) -> None:
    """One line on stderr, if anybody still reads it."""
    try:
        sys.stderr.write(line + "\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        silence(sys.stderr)


def interrupted(command: str | None) -> int:
    """Ctrl-C: one line, exit code 130."""
    say(f"nurbsmotion{' ' + command if command else ''}: interrupted")
    return EXIT_INTERRUPTED


def output_closed() -> int:
    """The reader of stdout (or stderr) left: say nothing more, exit code 141."""
    for stream in (sys.stdout, sys.stderr):
        if reader_gone(stream):
            silence(stream)
    return EXIT_BROKEN_PIPE
