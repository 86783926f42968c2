"""Machine axes: millimetres <-> drive counts, soft limits, per-axis limits for planners.

counts = round(sign * mm * counts_per_mm) + offset_counts,  sign = -1 if the axis is inverted
mm     = sign * (counts - offset_counts) / counts_per_mm

Every check happens on the whole (N, n_axes) array before any motion, and a failure names
the axis, the limit and the first offending cycle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nurbsmotion.config import AxisConfig, MachineConfig
from nurbsmotion.errors import InputError

INT32_MIN = -(2**31)
INT32_MAX = 2**31 - 1


@dataclass(frozen=True)
class AxisLimits:
    """Per-axis kinematic limits in mm/s and mm/s² (None = no axis limit configured)."""

    name: str
    max_velocity_mm_s: float | None
    max_accel_mm_s2: float | None


class AxisMap:
    """Converts positions of all configured axes between mm and drive counts."""

    def __init__(self, axes: tuple[AxisConfig, ...] | list[AxisConfig]) -> None:
        if not axes:
            raise InputError("axes", "needs at least one axis")
        self.axes = tuple(axes)
        self.names = tuple(a.name for a in self.axes)
        self.node_ids = tuple(a.node_id for a in self.axes)
        self.sign = np.array([-1.0 if a.invert else 1.0 for a in self.axes])
        self.counts_per_mm = np.array([float(a.counts_per_mm) for a in self.axes])
        self.offset_counts = np.array([int(a.offset_counts) for a in self.axes], dtype=np.int64)

    @classmethod
    def from_config(cls, config: MachineConfig) -> "AxisMap":
        return cls(config.axes)

    @property
    def n_axes(self) -> int:
        return len(self.axes)

    def limits(self) -> tuple[AxisLimits, ...]:
        """Per-axis velocity and acceleration limits (mm/s, mm/s²) for planners."""
        return tuple(AxisLimits(a.name, a.max_velocity_mm_s, a.max_accel_mm_s2) for a in self.axes)

    def max_accel_counts_s2(self, default_mm_s2: float) -> np.ndarray:
        """Per-axis acceleration limit in counts/s² (``default_mm_s2`` where none is set)."""
        acc = np.array([a.max_accel_mm_s2 if a.max_accel_mm_s2 is not None else default_mm_s2 for a in self.axes])
        return acc * self.counts_per_mm

    def following_error_window_counts(self) -> np.ndarray:
        """0x6065 values: the configured window in mm converted to counts (at least 1)."""
        w = np.array([a.following_error_window_mm for a in self.axes]) * self.counts_per_mm
        return np.maximum(np.round(w), 1).astype(np.int64)

    # ------------------------------------------------------------------ conversion
    def _as_positions(self, positions_mm: np.ndarray) -> np.ndarray:
        arr = np.asarray(positions_mm, dtype=float)
        if arr.ndim == 1:
            arr = arr.reshape(1, -1)
        if arr.ndim != 2 or arr.shape[1] != self.n_axes:
            raise InputError("set-points", f"expected an array of shape (N, {self.n_axes}) in mm "
                             f"(axes {', '.join(self.names)}), got shape {np.shape(positions_mm)}")
        return arr

    def check_soft_limits(self, positions_mm: np.ndarray) -> None:
        """Raise InputError for the first cycle (per axis order) leaving an axis' soft limits."""
        arr = self._as_positions(positions_mm)
        bad_nan = ~np.isfinite(arr)
        if bad_nan.any():
            cycle, axis = np.argwhere(bad_nan)[0]
            raise InputError(f"axis {self.names[axis]}", f"position is not finite at cycle {cycle}")
        for j, ax in enumerate(self.axes):
            if ax.soft_limits_mm is None:
                continue
            low, high = ax.soft_limits_mm
            for limit, outside in ((low, arr[:, j] < low), (high, arr[:, j] > high)):
                if outside.any():
                    cycle = int(np.argmax(outside))
                    raise InputError(f"axis {ax.name}", f"position {arr[cycle, j]:.6g} mm at cycle {cycle} is "
                                     f"outside the soft limit {limit:g} mm "
                                     f"(soft_limits_mm [{low:g}, {high:g}])")

    def to_counts(self, positions_mm: np.ndarray, check_limits: bool = True) -> np.ndarray:
        """(N, n_axes) mm -> (N, n_axes) int32 counts; soft-limit and int32 range checked."""
        arr = self._as_positions(positions_mm)
        if check_limits:
            self.check_soft_limits(arr)
        counts = np.rint(arr * (self.sign * self.counts_per_mm)) + self.offset_counts
        outside = (counts < INT32_MIN) | (counts > INT32_MAX) | ~np.isfinite(counts)
        if outside.any():
            cycle, axis = np.argwhere(outside)[0]
            raise InputError(f"axis {self.names[axis]}", f"position {arr[cycle, axis]:.6g} mm at cycle {cycle} "
                             f"is {counts[cycle, axis]:.0f} counts, outside the drive's int32 range")
        return counts.astype(np.int32)

    def to_mm(self, counts: np.ndarray) -> np.ndarray:
        """(N, n_axes) counts -> (N, n_axes) mm (inverse of :meth:`to_counts` up to rounding)."""
        arr = np.asarray(counts, dtype=np.int64)
        return (arr - self.offset_counts) * self.sign / self.counts_per_mm
