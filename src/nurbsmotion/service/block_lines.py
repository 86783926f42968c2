"""blocks.csv of a streamed job (service.records.BLOCK_LINES_FILE: the program line of each
block, row i block i, so an interrupted job's record names the line it reached), written by
the planner worker as the blocks are planned: the lines of every block up to the last one
planned, appended after each chunk and flushed, and the rest once the program is planned to
its end. The daemon never lists the lines of a whole program (10^6 blocks: a second of its
interpreter lock before first motion); a reader of the record finds every block the trace
names, because a chunk's blocks are written with it.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import IO

from nurbsmotion.log import kv
from nurbsmotion.program import Program
from nurbsmotion.service.job_common import block_lines
from nurbsmotion.service.records import BLOCK_LINES_FILE

log = logging.getLogger(__name__)


class BlockLinesFile:
    """The job record's blocks.csv, appended up to the blocks planned (module docstring)."""

    def __init__(self, program: Program) -> None:
        self.program = program
        self.written = 0  # blocks whose line is in the file
        self.wanted = 0  # blocks planned so far
        self.out: IO[str] | None = None
        self.failed = False  # the file cannot be written (logged once): the job goes on without it

    def reach(self, blocks: int) -> None:
        """Blocks [0, blocks) are planned."""
        self.wanted = max(self.wanted, min(blocks, len(self.program.blocks)))

    def write(self, folder: Path) -> None:
        """Append the lines of the blocks planned since the last write (the file begun in
        ``folder``, the record's, on the first) and flush. A failure to write is one log line:
        the record then names no line for an interruption, the job is not stopped for it."""
        if self.failed:
            return
        try:
            if self.out is None:
                self.out = open(folder / BLOCK_LINES_FILE, "w", encoding="ascii")
                self.out.write("line\n")
            if self.wanted > self.written:
                self.out.write("".join(f"{n}\n" for n in block_lines(self.program, self.written, self.wanted)))
                self.written = self.wanted
            self.out.flush()
        except OSError as err:
            self.failed = True
            log.warning(kv("block_lines_not_written", folder=folder, error=err))

    def close(self) -> None:
        if self.out is not None:
            try:
                self.out.close()
            except OSError as err:
                log.warning(kv("block_lines_not_written", error=err))
