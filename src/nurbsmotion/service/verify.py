"""What the simulated drives did versus what was planned, read from a job record.

Used by ``nurbsmotion demo`` to report the run and by the integration tests to prove that
the drives applied exactly the planned set-points.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nurbsmotion.axes import AxisMap
from nurbsmotion.config import MachineConfig
from nurbsmotion.planning.trace import read_trace
from nurbsmotion.service.records import DRIVES_DIR, TRACE_FILE
from nurbsmotion.sim import read_csv


def planned_counts(folder: Path, config: MachineConfig) -> np.ndarray:
    """The job's planned set-points in counts (N, n_axes), from its trace CSV."""
    trace = read_trace(folder / TRACE_FILE)
    xyz = np.column_stack([trace["x"], trace["y"], trace["z"]])
    columns = ["XYZ".index(a.name) for a in config.axes]
    return AxisMap.from_config(config).to_counts(xyz[:, columns], check_limits=False)


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


@dataclass(frozen=True)
class DriveReport:
    planned: int  # planned set-points
    applied: int  # rows the drives recorded during the job (incl. holding before/after)
    exact: bool  # the recording is the plan, held before and after
    max_following_error_mm: float  # max |set-point - actual| over the axes (servo model)


def drive_report(folder: Path, config: MachineConfig) -> DriveReport:
    plan = planned_counts(folder, config)
    setpoints, actual = recorded_counts(folder, config)
    cpm = np.array([a.counts_per_mm for a in config.axes])
    following = float((np.abs(setpoints - actual) / cpm).max()) if len(setpoints) else 0.0
    return DriveReport(len(plan), len(setpoints), held_plan_held(setpoints, plan), following)
