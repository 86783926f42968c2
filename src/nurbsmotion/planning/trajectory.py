"""Trajectory: the planned set-points, one per interpolation cycle, as numpy arrays."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable

import numpy as np
from numpy.typing import NDArray


@dataclass(eq=False)
class Trajectory:
    """Set-point i is commanded at t = i * period_s. Row 0 is the start point (at rest),
    the last row the end point (at rest).

    ``feed_mm_s[i]`` is the feed the planner commanded for the step ending at row i (row 0
    is 0): its own figure; what the drives really see is measured from ``position_mm`` by
    planning.measure.
    """

    algorithm: str
    period_s: float
    block: NDArray[np.int32]  # (N,) index of the program block of each set-point
    u: NDArray[np.float64]  # (N,) curve parameter within that block
    position_mm: NDArray[np.float64]  # (N, 3)
    feed_mm_s: NDArray[np.float64]  # (N,) commanded feed of the step ending at each row
    planning_time_s: float = 0.0
    notes: dict[str, float | str] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.u)

    @property
    def t_s(self) -> NDArray[np.float64]:
        return np.arange(len(self.u), dtype=np.float64) * self.period_s

    @property
    def duration_s(self) -> float:
        """Motion time: from the first set-point to the last."""
        return (len(self.u) - 1) * self.period_s

    @classmethod
    def concatenate(cls, chunks: Iterable["Trajectory"]) -> "Trajectory":
        """Join consecutive chunks of one plan (as produced by a chunked planner)."""
        parts = list(chunks)
        if not parts:
            raise ValueError("no chunks")
        first = parts[0]
        return cls(
            algorithm=first.algorithm,
            period_s=first.period_s,
            block=np.concatenate([p.block for p in parts]),
            u=np.concatenate([p.u for p in parts]),
            position_mm=np.concatenate([p.position_mm for p in parts]),
            feed_mm_s=np.concatenate([p.feed_mm_s for p in parts]),
            planning_time_s=sum(p.planning_time_s for p in parts),
            notes=dict(first.notes),
        )
