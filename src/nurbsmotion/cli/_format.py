"""Figures of the daemon's responses and records as text, for fields that may be null.

The daemon sends ``null`` for a figure not known yet (a streamed job's ``length_mm``,
``cycles``, ``duration_s`` until the planner worker has reached them; ``line_reached``
before the first set-point; a position actual before the first TPDO) and for every
non-finite number (docs/daemon.md, "Wire format"). A client formats them here: ``-``.
"""

from __future__ import annotations

from typing import Any

MISSING = "-"


def figure(value: Any, spec: str = "", unit: str = "") -> str:
    """``value`` formatted with ``spec`` and followed by ``unit``; ``-`` when it is null."""
    if value is None:
        return MISSING
    return f"{value:{spec}}{unit}"


def number(value: float | None, digits: int) -> str:
    """A figure with ``digits`` decimals, or ``-`` while it is not known."""
    return figure(value, f".{digits}f")


def reading_text(reading: dict[str, Any] | None) -> str | None:
    """A program's lines read (program.summary.reading_dict): '27 of 27 read', or '33 of 134
    read, to M30 at line 33; lines after M30 not read: 101' (LinuxCNC ignores them: said,
    never silent); None for a program without lines (YAML curves)."""
    if reading is None:
        return None
    text = f"{reading['last_line']} of {reading['lines_total']} read"
    if reading["ended_by"] != "end of file":
        text += f", to {reading['ended_by']} at line {reading['last_line']}"
    if reading["lines_not_read"]:
        text += f"; lines after {reading['ended_by']} not read: {reading['lines_not_read']}"
    return text
