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
