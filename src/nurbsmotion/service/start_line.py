"""Starting a job from a line of its program (``submit`` with ``start_line``; ``run --start-line``).

The request's field is checked here; the reader does the rest (program.gcode_start): it
rebuilds the modal state at the line, approaches it over the machine's safe Z
(``machine.safe_z_mm``, config.MachineConfig.safe_z_mm) and refuses, one line naming
``file:N``, where a restart is not safe.
"""

from __future__ import annotations

import dataclasses
import math

from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import InputError
from nurbsmotion.program import Program, ReadOptions, ResumeState

FIELD = "field 'start_line'"


def start_line_field(value: object) -> int | None:
    """The request's ``start_line``: absent, or a whole line number >= 1."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value) or value < 1:
        raise InputError(FIELD, f"must be a line number >= 1, got {value!r}")
    return int(value)


def resume_of(program: Program | None) -> ResumeState | None:
    """The state a job's program started from a line with, or None (from its first line)."""
    return program.resume if program is not None else None


def start_line_options(options: ReadOptions, start_line: int, config: MachineConfig) -> ReadOptions:
    """``options`` reading from ``start_line`` with the machine's safe Z (a machine without a Z
    axis never rises: -inf)."""
    safe_z = config.safe_z_mm()
    return dataclasses.replace(options, start_line=start_line, safe_z_mm=-math.inf if safe_z is None else safe_z)
