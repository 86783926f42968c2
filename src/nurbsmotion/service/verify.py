"""What the simulated drives did versus what was planned, read from a job record.

Used by ``nurbsmotion demo`` to report the run and by the integration tests to prove that
the drives applied exactly the planned set-points.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from nurbsmotion.axes import AxisMap
from nurbsmotion.config import MachineConfig
from nurbsmotion.planning.trace import read_trace
from nurbsmotion.service.records import CONFIG_FILE, DRIVES_DIR, TRACE_FILE
from nurbsmotion.sim import read_csv


def planned_counts(folder: Path, config: MachineConfig) -> np.ndarray:
    """The job's planned set-points in counts (N, n_axes), from its trace CSV, with the axis
    offsets the job ran with (its config.json: homing moves them)."""
    trace = read_trace(folder / TRACE_FILE)
    xyz = np.column_stack([trace["x"], trace["y"], trace["z"]])
    columns = ["XYZ".index(a.name) for a in config.axes]
    return AxisMap.from_config(offsets_in_force(folder, config)).to_counts(xyz[:, columns], check_limits=False)


def offsets_in_force(folder: Path, config: MachineConfig) -> MachineConfig:
    """``config`` with each axis' ``offset_counts`` as the record's config.json has it."""
    try:
        axes = json.loads((folder / CONFIG_FILE).read_text(encoding="utf-8"))["axes"]
        offsets = [int(a["offset_counts"]) for a in axes]
    except (OSError, ValueError, KeyError, TypeError):
        return config
    if len(offsets) != len(config.axes):
        return config
    return replace(config, axes=tuple(replace(a, offset_counts=o) for a, o in zip(config.axes, offsets)))


def recorded_counts(folder: Path, config: MachineConfig) -> tuple[np.ndarray, np.ndarray]:
    """(set-points, actual positions) the simulated drives applied, one row per SYNC."""
    setpoints, actual = [], []
    for axis in config.axes:
        records = read_csv(folder / DRIVES_DIR / f"node{axis.node_id}.csv")
        setpoints.append([r.setpoint_counts for r in records])
        actual.append([r.position_actual_counts for r in records])
    n = min(len(c) for c in setpoints)
    return np.array([c[:n] for c in setpoints]).T.reshape(n, -1), np.array([c[:n] for c in actual]).T.reshape(n, -1)


def held_plan_held(recorded: np.ndarray, plan: np.ndarray) -> bool:
    """recorded == [plan[0]] * k + plan + [plan[-1]] * m for some k, m >= 0: every planned
    set-point applied once, in order, nothing else but holding before and after."""
    n = len(plan)
    for start in range(len(recorded) - n + 1):
        if np.array_equal(recorded[start:start + n], plan) and (recorded[:start] == plan[0]).all() \
                and (recorded[start + n:] == plan[-1]).all():
            return True
    return False


def plan_with_holds(recorded: np.ndarray, plan: np.ndarray) -> bool:
    """recorded is the plan with some rows repeated in place (holding before, during a pause
    or hold at rest, and after): every planned set-point applied once, in order, nothing else."""
    i, n = 0, len(plan)
    for row in recorded:
        if i < n and np.array_equal(row, plan[i]):
            i += 1
        elif not np.array_equal(row, plan[max(i - 1, 0)]):
            return False
    return i == n


def rest_waits(recorded: np.ndarray, plan: np.ndarray) -> int | None:
    """How many rows ``recorded`` holds in the middle of the plan, where the plan itself is
    at rest (a row equal to the one before it: a streamed job whose chunk ended at rest waits
    there for the next one, docs/daemon.md); None if it is not the plan, each row once, in
    order, held only before, after and at such rests."""
    plan = np.asarray(plan)
    recorded = np.asarray(recorded)
    n, i, waits = len(plan), 0, 0
    at_rest = np.zeros(n, dtype=bool)
    at_rest[1:] = (plan[1:] == plan[:-1]).all(axis=1)
    for row in recorded:
        if i < n and np.array_equal(row, plan[i]):
            i += 1
        elif not np.array_equal(row, plan[max(i - 1, 0)]):
            return None
        elif 1 < i < n:  # held in the middle: only where the plan rests
            if not at_rest[i - 1]:
                return None
            waits += 1
    return waits if i == n else None


def on_planned_path(recorded: np.ndarray, plan: np.ndarray, tolerance_counts: float = 1.0) -> bool:
    """Every recorded row lies on the planned polyline (within ``tolerance_counts`` per axis,
    the rounding of an interpolated set-point), never moving backwards along it, ending on
    the last planned row: what a hold's stop ramp and resume ramp may send."""
    plan = np.asarray(plan, dtype=float)
    seg, frac = 0, 0.0
    for row in np.asarray(recorded, dtype=float):
        for j in range(seg, len(plan) - 1):
            a, d = plan[j], plan[j + 1] - plan[j]
            dd = float(d @ d)
            f = float(np.clip((row - a) @ d / dd, 0.0, 1.0)) if dd else 0.0
            if np.abs(a + f * d - row).max() <= tolerance_counts and (j > seg or f >= frac - 1e-9):
                seg, frac = j, f
                break
        else:
            if not (len(plan) == 1 and np.abs(plan[0] - row).max() <= tolerance_counts):
                return False
    return bool(np.abs(np.asarray(recorded, dtype=float)[-1] - plan[-1]).max() <= tolerance_counts)


@dataclass(frozen=True)
class DriveReport:
    planned: int  # planned set-points
    applied: int  # rows the drives recorded during the job (incl. holding before/after)
    exact: bool  # the recording is the plan, held before and after and only where the plan rests
    max_following_error_mm: float  # max |set-point - actual| over the axes (servo model)
    rest_waits: int = 0  # cycles held where the plan rests, waiting for a streamed job's next chunk


def drive_report(folder: Path, config: MachineConfig) -> DriveReport:
    plan = planned_counts(folder, config)
    setpoints, actual = recorded_counts(folder, config)
    cpm = np.array([a.counts_per_mm for a in config.axes])
    following = float((np.abs(setpoints - actual) / cpm).max()) if len(setpoints) else 0.0
    waits = rest_waits(setpoints, plan)
    return DriveReport(len(plan), len(setpoints), waits is not None, following, waits or 0)
