"""PlanLimits: the plain input record of every planner (ruckig-style: all limits explicit)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

from nurbsmotion.config import InterpolationConfig, MachineConfig
from nurbsmotion.errors import InputError
from nurbsmotion.program.model import AXES


@dataclass(frozen=True)
class PlanLimits:
    """Everything a planner needs besides the path. Units are in the names.

    ``feed_mm_s`` overrides every block's programmed feed when set (CLI --feed-mm-min);
    ``default_feed_mm_s`` applies to blocks that carry no feed. ``max_jerk_mm_s3`` None
    means no jerk limit. ``acc_time_s`` is Wang's linear acc/dec time t_l (a_l = V0 / t_l).
    Per-axis limits are tuples in axis order (X, Y, Z), None when not limited.
    """

    period_s: float = 0.004
    chord_error_mm: float = 0.01
    max_accel_mm_s2: float = 2500.0
    max_jerk_mm_s3: float | None = None
    feed_mm_s: float | None = None
    default_feed_mm_s: float = 200.0
    rapid_feed_mm_s: float = 200.0
    acc_time_s: float = 1.2
    junction_deviation_mm: float = 0.01
    path_tolerance_mm: float = 0.01  # corner blends' largest distance from the program (G64 P overrides; 0: no blends)
    smoothing: bool = True  # short-segment runs merged and fitted within the path tolerance (G64 Q overrides; smoothing.py)
    # Per-axis X, Y, Z limits; a None entry is an axis the configuration gives no limit for.
    axis_max_velocity_mm_s: tuple[float | None, ...] | None = None
    axis_max_accel_mm_s2: tuple[float | None, ...] | None = None

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "smoothing":
                if not isinstance(value, bool):
                    raise InputError(f.name, f"must be true or false, got {value!r}")
                continue
            values = value if isinstance(value, tuple) else (value,)
            for v in values:
                if v is None and f.name in ("max_jerk_mm_s3", "feed_mm_s", "axis_max_velocity_mm_s", "axis_max_accel_mm_s2"):
                    continue
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise InputError(f.name, f"must be a finite number, got {v!r}")
                zero_ok = f.name in ("junction_deviation_mm", "path_tolerance_mm")
                if not (v >= 0 if zero_ok else v > 0):
                    raise InputError(f.name, f"must be {'>= 0' if zero_ok else '> 0'}, got {v!r}")
        if self.period_s > 0.1:
            raise InputError("period_s", f"interpolation period {self.period_s * 1000:g} ms is longer than 100 ms")

    def feed_for(self, programmed_mm_s: float | None, rapid: bool = False) -> float:
        """The feed a block runs at: rapid feed, the override, the programmed F, or the default."""
        if rapid:
            return self.rapid_feed_mm_s
        if self.feed_mm_s is not None:
            return self.feed_mm_s
        return programmed_mm_s if programmed_mm_s is not None else self.default_feed_mm_s


def axis_limits(config: MachineConfig, attribute: str) -> tuple[float | None, ...] | None:
    """Per-axis limit in X, Y, Z order from the configuration's axes (None where not given)."""
    by_name = {axis.name.upper(): getattr(axis, attribute) for axis in config.axes}
    values = tuple(by_name.get(name) for name in AXES)
    return values if any(v is not None for v in values) else None


def limits_from_config(config: MachineConfig) -> PlanLimits:
    """The limits a job plans with on this machine: the configuration's interpolation
    defaults, cycle period and per-axis limits (``plan --config`` and the daemon alike)."""
    return replace(interpolation_limits(config.interpolation), period_s=config.cycle_period_s,
                   axis_max_velocity_mm_s=axis_limits(config, "max_velocity_mm_s"),
                   axis_max_accel_mm_s2=axis_limits(config, "max_accel_mm_s2"))


def interpolation_limits(interp: InterpolationConfig) -> PlanLimits:
    """The limits of an ``interpolation`` section alone (PlanLimits' period, no per-axis limits);
    of InterpolationConfig(): what a machine configuration that sets none plans with (``plan``
    without --config)."""
    return PlanLimits(
        chord_error_mm=interp.chord_error_mm,
        max_accel_mm_s2=interp.max_accel_mm_s2,
        max_jerk_mm_s3=interp.max_jerk_mm_s3,
        default_feed_mm_s=interp.feed_mm_s,
        rapid_feed_mm_s=interp.rapid_feed_mm_s,
        acc_time_s=interp.acc_time_s,
        junction_deviation_mm=interp.junction_deviation_mm,
        path_tolerance_mm=interp.path_tolerance_mm,
        smoothing=interp.smoothing,
    )
