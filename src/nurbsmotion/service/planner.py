"""Program text -> checked, fully planned job: the one place the service calls the program
readers, the planners and the axis map.

plan_job(name, text, config, start_mm) parses the program, plans it with the configured
algorithm, maps XYZ onto the configured axes, checks soft limits and converts to counts.
Every failure is an InputError naming file:line (or the axis and cycle); nothing moves.
"""

from __future__ import annotations

import re
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from nurbsmotion.axes import AxisMap
from nurbsmotion.planning.limits import limits_from_config
from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import InputError
from nurbsmotion.planning import Trajectory, plan
from nurbsmotion.planning.lookahead.planned_path import PlannedPath
from nurbsmotion.planning.measure import measure
from nurbsmotion.program import AXES, Program, ReadOptions
from nurbsmotion.program.summary import reading_dict
from nurbsmotion.service.job_common import JOG_NAME, MDI_NAME, JobPause, PlannedJob, axis_columns, parse
from nurbsmotion.service.planner_worker import PlannerWorker
from nurbsmotion.service.program_file import ProgramFile
from nurbsmotion.service.program_gate import check_machine_can_run
from nurbsmotion.service.rate import max_rate
from nurbsmotion.service.checked_store import CheckedStore
from nurbsmotion.service.streamed_job import StreamedJob, prepare_streamed_job

if TYPE_CHECKING:
    from nurbsmotion.service.program_check import ProgramChecker


def pause_rows(program: Program, trajectory: Trajectory) -> tuple[JobPause, ...]:
    """The rows where the program's holding events (``event.holds``) happen. An event after the
    last move is left out: the job ends there anyway."""
    pauses = []
    for event in program.events:
        if not event.holds:
            continue
        row = int(np.searchsorted(trajectory.block, event.before_block, side="left"))
        if row >= len(trajectory) - 1:
            continue
        if event.tool is not None and event.kind.value == "tool_change":
            reason, tool = f"{event.code} tool change to T{event.tool} at {event.source}", event.tool
        else:
            reason, tool = f"{event.code} at {event.source}", None
        pauses.append(JobPause(row, reason, tool))
    return tuple(pauses)


def axis_positions(trajectory: Trajectory, config: MachineConfig, source: str) -> np.ndarray:
    """(N, n_axes) positions of the configured axes; unconfigured program axes must not move."""
    columns = axis_columns(config)
    pos = trajectory.position_mm
    for j, name in enumerate(AXES):
        if j not in columns and len(pos) and np.ptp(pos[:, j]) > 1e-9:
            raise InputError(source, f"the program moves {name}, which this machine has no axis for")
    return pos[:, columns]


def soft_limit_error(positions: np.ndarray, trajectory: Trajectory, program: Program,
                     config: MachineConfig) -> InputError | None:
    """The first set-point (in program order) beyond an axis' soft limit, as the error of its
    program line: ``part.nc:42: X650: axis X would reach 650 mm, beyond the soft limit 600 mm``
    (the farthest the axis gets within that block; the word only when it is that position,
    not for an arc's bulge or an incremental or offset coordinate)."""
    first: tuple[int, int, float] | None = None  # cycle, axis, limit
    for j, axis in enumerate(config.axes):
        if axis.soft_limits_mm is None:
            continue
        for limit, outside in ((axis.soft_limits_mm[1], positions[:, j] > axis.soft_limits_mm[1]),
                               (axis.soft_limits_mm[0], positions[:, j] < axis.soft_limits_mm[0])):
            if outside.any() and (first is None or int(np.argmax(outside)) < first[0]):
                first = (int(np.argmax(outside)), j, limit)
    if first is None:
        return None
    cycle, j, limit = first
    block = int(trajectory.block[cycle])
    # the block's set-points and its programmed end: a corner blend (planning.lookahead.blend)
    # passes within the path tolerance of the end, the program asked for the end itself
    end = program.blocks[block].end[axis_columns(config)[j]]
    in_block = np.append(positions[trajectory.block == block, j], end)
    reached = float(in_block.max() if limit == config.axes[j].soft_limits_mm[1] else in_block.min())
    source = program.blocks[block].source
    name = config.axes[j].name
    word = re.search(rf"(?<![A-Za-z]){name}\s*([-+]?(\d+\.?\d*|\.\d+))", source.text, re.IGNORECASE)
    named = word is not None and abs(float(word.group(1)) - reached) < 1e-6  # the word is the cause (not an arc's bulge)
    where = f"{source}: {word.group(0).replace(' ', '')}" if named else str(source)
    return InputError(where, f"axis {name} would reach {reached:.6g} mm, beyond the soft limit {limit:g} mm")


def prepare_job(name: str, text: str | ProgramFile, config: MachineConfig, start_mm: np.ndarray | None = None,
                options: ReadOptions | None = None, worker: PlannerWorker | None = None,
                store: CheckedStore | None = None, checker: ProgramChecker | None = None) -> PlannedJob | StreamedJob:
    """The daemon's planner: the lookahead planner streams the job while it runs in the
    planner worker (service.streamed_job, checked completely first, or loaded checked from
    ``store``; a large program checked by ``checker`` first); the papers' methods plan it
    whole, and so are MDI lines (one line: planned at once; one without motion runs as a
    still job, which a streamed job cannot be)."""
    if config.interpolation.algorithm == "lookahead" and worker is not None and name != MDI_NAME:
        return prepare_streamed_job(name, text, config, worker, start_mm, options,
                                    store=store if name != JOG_NAME else None,  # a jog: a new line each time
                                    checker=checker)
    return plan_job(name, text if isinstance(text, str) else text.read_text(), config, start_mm, options)


def needs_planner_worker(config: MachineConfig) -> bool:
    """The daemon streams lookahead jobs from a planner worker process (service.planner_worker);
    their spindle, coolant and output events come with the chunks (service.streamed_job)."""
    return config.interpolation.algorithm == "lookahead"


STILL_ROWS = 2  # a job without motion: the held position twice, so row 0 can be a pause row (< last)


def still_trajectory(program: Program, period_s: float) -> Trajectory:
    """The trajectory of MDI lines without motion (``M3 S1000``, ``M8``, ``M64 P4``, ``G54``):
    STILL_ROWS rows at the start position, every event at row 0, so the job runs them (and
    waits for the spindle at speed there) like any job's events, without moving an axis."""
    rows = STILL_ROWS
    return Trajectory(algorithm="none (no motion)", period_s=period_s, block=np.zeros(rows, dtype=np.int32),
                      u=np.zeros(rows), position_mm=np.tile(np.asarray(program.start_position, dtype=float), (rows, 1)),
                      feed_mm_s=np.zeros(rows))


def plan_job(name: str, text: str, config: MachineConfig, start_mm: np.ndarray | None = None,
             options: ReadOptions | None = None) -> PlannedJob:
    """Parse, plan, check and convert ``text`` (see the module docstring). ``options``: the
    reader's start (persisted offsets, tool, switches); default: the machine's tool table."""
    axis_map = AxisMap.from_config(config)
    start_xyz = np.zeros(len(AXES))
    if start_mm is not None:
        start_xyz[axis_columns(config)] = start_mm
    program = parse(name, text, start_xyz, options or ReadOptions(tool_table=config.tool_table))
    check_machine_can_run(program, config)  # spindle, coolant, holds: before any planning
    if not program.blocks and name != MDI_NAME:
        raise InputError(name, "the program has no motion")
    t0 = time.perf_counter()
    try:
        trajectory = plan(program, limits_from_config(config), config.interpolation.algorithm) if program.blocks \
            else still_trajectory(program, config.cycle_period_s)
    except InputError as err:  # a planner names 'block N': say which program it is
        raise InputError(f"{name}: {err.where}" if err.where else name, err.message) from None
    planning_s = time.perf_counter() - t0
    positions = axis_positions(trajectory, config, name)
    beyond = soft_limit_error(positions, trajectory, program, config)
    if beyond is not None:
        raise beyond
    try:
        counts = axis_map.to_counts(positions)
    except InputError as err:
        raise InputError(f"{name}: {err.where}", err.message) from None
    path = PlannedPath.for_algorithm(program, limits_from_config(config), config.interpolation.algorithm)
    measured = measure(path.rows(trajectory), path.program)  # on the path planned: corner blends
    columns = axis_columns(config)
    v_peak = np.array(measured.axis_max_velocity_mm_s)[columns]
    a_peak = np.array(measured.axis_max_accel_mm_s2)[columns]
    rate = max_rate(v_peak, a_peak, [a.max_velocity_mm_s for a in config.axes],
                    [a.max_accel_mm_s2 or config.interpolation.max_accel_mm_s2 for a in config.axes])
    summary = plan_summary(name, program, trajectory, config, v_peak, a_peak, rate, planning_s)
    summary["measured"] = measured.summary()
    pauses = pause_rows(program, trajectory)
    summary["pauses"] = [{"row": p.row, "reason": p.reason} for p in pauses]
    return PlannedJob(trajectory, counts, summary, rate, program, measured, pauses)


def plan_summary(name: str, program: Program, trajectory: Trajectory, config: MachineConfig, v_peak: np.ndarray,
                 a_peak: np.ndarray, rate: float, planning_s: float) -> dict[str, Any]:
    """The plan.json of a job record (the measured figures are added by plan_job)."""
    return {
        "program": name, "blocks": len(program.blocks), "reading": reading_dict(program),
        "length_mm": round(program.length_mm, 6), "algorithm": trajectory.algorithm, "period_s": trajectory.period_s, "cycles": len(trajectory),
        "duration_s": round(trajectory.duration_s, 6), "planning_time_s": round(planning_s, 6),
        "max_feed_mm_s": round(float(np.max(trajectory.feed_mm_s)), 6) if len(trajectory) else 0.0,
        "axes": [{"name": a.name, "node": a.node_id, "max_velocity_mm_s": round(float(v), 6),
                  "max_accel_mm_s2": round(float(acc), 6)} for a, v, acc in zip(config.axes, v_peak, a_peak)],
        "start_mm": [round(float(x), 6) for x in trajectory.position_mm[0]],
        "end_mm": [round(float(x), 6) for x in trajectory.position_mm[-1]],
        "max_override_percent": round(max(1.0, rate) * 100.0, 3),
        "notes": {k: v for k, v in trajectory.notes.items()},
    }
