"""``nurbsmotion plan PROGRAM``: interpolate a program cycle by cycle and report measured figures.

The figures are measured on the set-points (planning.measure), never the planner's own
estimates: true chord error, resultant acceleration (second differences / T²), jerk (third
differences / T³), feed fluctuation, end-point error. ``--trace`` writes the per-cycle CSV,
``--plot`` a PNG like Wang's Figures 5-9.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

from nurbsmotion.steps import drained
from nurbsmotion.cli._forked import IdleWatch, cores_available, forked_iteration
from nurbsmotion.cli._planning_options import add_planning_arguments, limits_summary, planner, planning_setup
from nurbsmotion.errors import InputError
from nurbsmotion.planning import ALGORITHM_MODULES, PlanLimits, Trajectory
from nurbsmotion.planning.lookahead import PlanStream
from nurbsmotion.planning.lookahead.api import ALGORITHM
from nurbsmotion.planning.measure import Measurements, MeasureStream
from nurbsmotion.planning.trace import TraceWriter
from nurbsmotion.program import BlockKind, Program

if TYPE_CHECKING:
    from nurbsmotion.planning.lookahead.planned_path import PlannedPath

log = logging.getLogger(__name__)

HELP = "interpolate a program cycle by cycle and report the measured chord error, acceleration, jerk"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_planning_arguments(parser)
    parser.add_argument("--algorithm", choices=list(ALGORITHM_MODULES), metavar="NAME",
                        help=f"one of {', '.join(ALGORITHM_MODULES)} (default: the config's, else lookahead)")
    parser.add_argument("--trace", metavar="OUT.csv", help="write the per-cycle trace CSV")
    parser.add_argument("--plot", metavar="OUT.png", help="write a PNG of path, curvature, feed, chord error, acceleration, jerk")
    parser.add_argument("--processes", choices=("auto", "1", "2"), default="auto",
                        help="2: the look-ahead planner in a second process while this one measures; 1: one process; "
                             "auto (default): 2 when a CPU stood idle while the program was read")


def guarantees(trajectory: "Trajectory | PlanSummary", limits: PlanLimits) -> list[dict[str, object]]:
    """What a planner that verifies its set-points (lookahead) guarantees on every cycle: each
    limit with the largest figure its own check measured (Trajectory.notes). Empty for the
    papers' methods, which check nothing."""
    notes = trajectory.notes
    if "guarantees" not in notes:
        return []

    def row(name: str, limit: object, verified: object, unit: str, how: str) -> dict[str, object]:
        return {"limit": name, "at_most": limit, "verified_max": verified, "unit": unit, "how": how}

    rows = [row("chord error", limits.chord_error_mm, notes.get("verified_max_chord_error_mm"), "mm",
                "bound kappa_max L^2/8 per step; sampled across block junctions"),
            row("resultant acceleration", limits.max_accel_mm_s2, notes.get("verified_max_accel_mm_s2"), "mm/s^2",
                "second difference / T^2")]
    if limits.max_jerk_mm_s3 is not None:
        rows.append(row("jerk", limits.max_jerk_mm_s3, notes.get("verified_max_jerk_mm_s3"), "mm/s^3",
                        "third difference / T^3"))
    for i, axis in enumerate("xyz"):
        if limits.axis_max_velocity_mm_s is not None and i < len(limits.axis_max_velocity_mm_s):
            rows.append(row(f"{axis.upper()} velocity", limits.axis_max_velocity_mm_s[i],
                            notes.get(f"verified_max_{axis}_velocity_mm_s"), "mm/s", "step / T"))
        if limits.axis_max_accel_mm_s2 is not None and i < len(limits.axis_max_accel_mm_s2):
            rows.append(row(f"{axis.upper()} acceleration", limits.axis_max_accel_mm_s2[i],
                            notes.get(f"verified_max_{axis}_accel_mm_s2"), "mm/s^2", "second difference / T^2"))
    rows.append(row("feed fluctuation", notes.get("fluctuation_limit"), notes.get("verified_max_arc_fluctuation"), "",
                    "|arc length of the step - planned step| / planned step"))
    return rows


def format_guarantees(trajectory: "Trajectory | PlanSummary", limits: PlanLimits) -> list[str]:
    rows = guarantees(trajectory, limits)
    if not rows:
        return []
    notes = trajectory.notes
    lines = [f"guaranteed on every cycle (checked by the planner, tolerance {notes.get('tolerance', 0):g} relative, "
             f"planned at {notes.get('planning_margin', 1) * 100:g} % of each limit):"]
    for r in rows:
        verified = r["verified_max"]
        shown = f"{verified:.6g}" if isinstance(verified, float) else "-"
        lines.append(f"  {r['limit']:<24} <= {r['at_most']:<10g} verified max {shown} {r['unit']}".rstrip())
    lines.append("  end point                exact, at rest on a cycle boundary")
    return lines


def fallbacks(notes: dict) -> str:
    """The planner's fallbacks (docs/lookahead.md, 'No give-ups'), when it needed any."""
    stops, slower = int(notes.get("fallback_stops", 0)), int(notes.get("fallback_slower_blocks", 0))
    if not stops and not slower:
        return ""
    return f"; {stops} of them added where repairs failed, {slower} blocks at a lower feed"


def format_summary(program: Program, trajectory: "Trajectory | PlanSummary", m: Measurements, limits: PlanLimits) -> str:
    rate = m.cycles / trajectory.planning_time_s if trajectory.planning_time_s > 0 else float("inf")
    return "\n".join([
        f"program      {program.name}: {len(program.blocks)} blocks, {program.length_mm:.3f} mm",
        f"algorithm    {trajectory.algorithm}: T {limits.period_s * 1000:g} ms, chord error <= {limits.chord_error_mm:g} mm, "
        f"acceleration <= {limits.max_accel_mm_s2:g} mm/s^2, acc/dec time {limits.acc_time_s:g} s",
        f"cycles       {m.cycles} (motion time {m.duration_s:.3f} s, {trajectory.notes.get('stops', 0)} stops{fallbacks(trajectory.notes)})",
        f"length       {m.length_mm:.3f} mm along the set-points",
        "measured on the set-points:",
        f"  max chord error          {m.max_chord_error_mm * 1000:.4f} um (min {m.min_chord_error_mm * 1000:.4f} um)",
        f"  max resultant accel      {m.max_accel_mm_s2:.1f} mm/s^2",
        f"  max jerk                 {m.max_jerk_mm_s3:.4g} mm/s^3",
        f"  max feed                 {m.max_speed_mm_s:.3f} mm/s",
        f"  max feed fluctuation     {m.max_fluctuation:.3e}",
        f"  end point error          {m.end_error_mm:.3e} mm",
        "  axis max velocity        " + " ".join(f"{a} {v:.1f}" for a, v in zip("XYZ", m.axis_max_velocity_mm_s)) + " mm/s",
        "  axis max acceleration    " + " ".join(f"{a} {v:.0f}" for a, v in zip("XYZ", m.axis_max_accel_mm_s2)) + " mm/s^2",
        *format_guarantees(trajectory, limits),
        f"planning     {trajectory.planning_time_s * 1000:.1f} ms ({rate:,.0f} set-points/s)",
    ])


STREAM_CHUNK_CYCLES = 20000  # set-points per chunk when streaming (lookahead): memory ~ one window


@dataclass(eq=False)
class PlanSummary:
    """What the report needs of a plan streamed through: its notes and planning time (the
    set-points themselves went to the trace and the measurements chunk by chunk)."""

    algorithm: str
    planning_time_s: float
    notes: dict[str, float | str]


# idle CPUs while the program was read (beside this process) that make a second process
# worth it: a free core read 0.9-1.0 here, one shared with bursty work in between
IDLE_CORES_TO_FORK = 0.75


def second_process_helps(watch: IdleWatch) -> bool:
    """Whether to plan in a second process: two cores or more, and on average at least
    IDLE_CORES_TO_FORK of them idle since ``watch`` started (unknown counts as idle)."""
    if cores_available() < 2:
        return False
    idle = watch.idle_cores()
    log.debug("idle CPUs while reading: %s", "unknown" if idle is None else f"{idle:.2f}")
    return idle is None or idle >= IDLE_CORES_TO_FORK


def streamed_plan(name: str, program: Program, limits: PlanLimits, chunks_out: Callable[[Trajectory], None],
                  forked: bool = False, stream: PlanStream | None = None) -> PlanSummary:
    """Plan and hand every chunk to ``chunks_out``: the lookahead planner in bounded memory
    (``stream``, or a PlanStream made here; ``forked``: in a second process, so that planning
    the next chunk overlaps measuring and writing this one: cli._forked), the papers' methods
    as one whole trajectory."""
    if name == ALGORITHM:
        stream = PlanStream(program, limits, STREAM_CHUNK_CYCLES) if stream is None else stream

        def summary() -> PlanSummary:
            return PlanSummary(name, stream.planning_time_s, stream.notes)

        if forked:
            return drained(forked_iteration(lambda: stream, summary), chunks_out)
        for chunk in stream:
            chunks_out(chunk)
        return summary()
    trajectory = planner(name)(program, limits)
    chunks_out(trajectory)
    return PlanSummary(trajectory.algorithm, trajectory.planning_time_s, trajectory.notes)


class PathRuler:
    """The MeasureStream on the path planned (PlannedPath: blends as blocks of their own),
    made at the first chunk.

    In one process (``stream``: the PlanStream planning here) the path is the pieces the
    stream sets up (PlannedPath.streamed, as the daemon's planner worker measures), not a
    second set-up of the whole program: 0.1-0.24 s of CPU on HSM_test, braid, V-carve.
    A program of NURBS blocks only has no blends (they join lines and arcs), so its path is
    the program itself, without the block-to-piece lookup of every set-point (0.07 s for
    Wang x 100). With the planner in a forked process the path is set up here, after the
    fork, beside the planner."""

    def __init__(self, program: Program, limits: PlanLimits, name: str, keep_rows: bool,
                 stream: PlanStream | None = None) -> None:
        self.program, self.limits, self.name, self.keep_rows = program, limits, name, keep_rows
        self.stream = stream
        self.made: tuple[PlannedPath, MeasureStream] | None = None

    def ready(self) -> tuple[PlannedPath, MeasureStream]:
        if self.made is None:
            from nurbsmotion.planning.lookahead.planned_path import PlannedPath

            stream = self.stream
            if stream is not None and any(b.kind is not BlockKind.NURBS for b in self.program.blocks):
                path = PlannedPath.streamed(self.program, lambda: stream.pieces_set_up)
            else:
                path = PlannedPath.for_algorithm(self.program, self.limits, self.name)
            self.made = path, MeasureStream(path.program, keep_rows=self.keep_rows)
        return self.made


def measured_plan(args: argparse.Namespace, program: Program, limits: PlanLimits, name: str,
                  forked: bool = False) -> tuple[PlanSummary, Measurements, Trajectory | None]:
    """Plan (``forked``: in a second process), measure and write the trace chunk by chunk;
    the whole trajectory is kept only for --plot."""
    stream = PlanStream(program, limits, STREAM_CHUNK_CYCLES) if name == ALGORITHM else None
    ruler = PathRuler(program, limits, name, bool(args.plot), None if forked else stream)
    trace = TraceWriter(args.trace) if args.trace else None
    kept: list[Trajectory] = []

    def consume(chunk: Trajectory) -> None:
        path, measuring = ruler.ready()
        figures = measuring.add(path.rows(chunk))
        if figures is not None and trace is not None:
            trace.write(path.on_program(figures))
        if args.plot:
            kept.append(chunk)

    try:
        summary = streamed_plan(name, program, limits, consume, forked, stream=stream)
        path, measuring = ruler.ready()
        last = measuring.finish()
        if last is not None and trace is not None:
            trace.write(path.on_program(last))
    except BaseException:
        if trace is not None:
            trace.discard()
        raise
    if trace is not None:
        trace.close()
    return summary, measuring.measurements(), Trajectory.concatenate(kept) if kept else None


def error_json(err: InputError) -> str:
    """The --json answer when the command fails: one error object (where, message)."""
    return json.dumps({"error": {"where": err.where, "message": err.message, "text": str(err)}}, indent=2)


def run(args: argparse.Namespace) -> int:
    try:
        return plan_and_report(args)
    except InputError as err:
        if args.json:
            print(error_json(err))
            sys.stdout.flush()
        raise


def plan_and_report(args: argparse.Namespace) -> int:
    watch = IdleWatch()  # the machine's idle CPUs while the program is read
    program, limits, default = planning_setup(args)
    name = args.algorithm or default
    planner(name)  # an unknown algorithm is an error before anything is planned
    if args.plot:
        from nurbsmotion.planning.plot import require_matplotlib

        require_matplotlib()
    forked = second_process_helps(watch) if args.processes == "auto" else args.processes == "2"
    plan, m, whole = measured_plan(args, program, limits, name, forked)
    if args.plot:
        from nurbsmotion.planning.plot import plot_run

        assert whole is not None, "measured_plan keeps the whole trajectory whenever --plot is given"
        plot_run(args.plot, program, whole, m, limits)
    if args.json:
        print(json.dumps({"program": program.name, "algorithm": plan.algorithm, "limits": limits_summary(limits),
                          "planning_time_s": plan.planning_time_s, "measured": m.summary(),
                          "guarantees": guarantees(plan, limits), "tolerance": plan.notes.get("tolerance"),
                          "notes": plan.notes, "trace": args.trace, "plot": args.plot}, indent=2))
    else:
        print(format_summary(program, plan, m, limits))
    sys.stdout.flush()
    return 0
