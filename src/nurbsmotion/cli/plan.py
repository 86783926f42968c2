"""``nurbsmotion plan PROGRAM``: interpolate a program cycle by cycle and report measured figures.

The figures are measured on the set-points (planning.measure), never the planner's own
estimates: true chord error, resultant acceleration (second differences / T²), jerk (third
differences / T³), feed fluctuation, end-point error. ``--trace`` writes the per-cycle CSV,
``--plot`` a PNG like Wang's Figures 5-9.
"""

from __future__ import annotations

import argparse
import json
import sys

from nurbsmotion.cli._planning_options import add_planning_arguments, limits_summary, planner, planning_setup
from nurbsmotion.planning import ALGORITHM_MODULES, PlanLimits, Trajectory
from nurbsmotion.planning.measure import Measurements, measure
from nurbsmotion.planning.trace import write_trace
from nurbsmotion.program import Program

HELP = "interpolate a program cycle by cycle and report the measured chord error, acceleration, jerk"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_planning_arguments(parser)
    parser.add_argument("--algorithm", choices=list(ALGORITHM_MODULES), metavar="NAME",
                        help=f"one of {', '.join(ALGORITHM_MODULES)} (default: the config's, else lookahead)")
    parser.add_argument("--trace", metavar="OUT.csv", help="write the per-cycle trace CSV")
    parser.add_argument("--plot", metavar="OUT.png", help="write a PNG of path, curvature, feed, chord error, acceleration, jerk")


def format_summary(program: Program, trajectory: Trajectory, m: Measurements, limits: PlanLimits) -> str:
    rate = m.cycles / trajectory.planning_time_s if trajectory.planning_time_s > 0 else float("inf")
    return "\n".join([
        f"program      {program.name}: {len(program.blocks)} blocks, {program.length_mm:.3f} mm",
        f"algorithm    {trajectory.algorithm}: T {limits.period_s * 1000:g} ms, chord error <= {limits.chord_error_mm:g} mm, "
        f"acceleration <= {limits.max_accel_mm_s2:g} mm/s^2, acc/dec time {limits.acc_time_s:g} s",
        f"cycles       {m.cycles} (motion time {m.duration_s:.3f} s, {trajectory.notes.get('stops', 0)} stops)",
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
        f"planning     {trajectory.planning_time_s * 1000:.1f} ms ({rate:,.0f} set-points/s)",
    ])


def run(args: argparse.Namespace) -> int:
    program, limits, default = planning_setup(args)
    name = args.algorithm or default
    plan_fn = planner(name)
    if args.plot:
        from nurbsmotion.planning.plot import require_matplotlib

        require_matplotlib()
    trajectory = plan_fn(program, limits)
    m = measure(trajectory, program)
    if args.trace:
        write_trace(args.trace, trajectory, m)
    if args.plot:
        from nurbsmotion.planning.plot import plot_run

        plot_run(args.plot, program, trajectory, m, limits)
    if args.json:
        print(json.dumps({"program": program.name, "algorithm": trajectory.algorithm, "limits": limits_summary(limits),
                          "planning_time_s": trajectory.planning_time_s, "measured": m.summary(),
                          "trace": args.trace, "plot": args.plot}, indent=2))
    else:
        print(format_summary(program, trajectory, m, limits))
    sys.stdout.flush()
    return 0
