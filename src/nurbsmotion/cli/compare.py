"""``nurbsmotion compare PROGRAM``: every algorithm on the same program and limits, one table.

Like Zhang's comparison table (interpolation time, max and min chord error), extended with
the measured resultant acceleration, feed fluctuation and end-point error. An algorithm
whose module is not installed (e.g. ``lookahead`` before it is merged) is skipped with a note.
"""

from __future__ import annotations

import argparse
import json
import sys

from nurbsmotion.cli._planning_options import add_planning_arguments, limits_summary, planner, planning_setup
from nurbsmotion.errors import InputError
from nurbsmotion.planning import ALGORITHM_MODULES
from nurbsmotion.planning.lookahead.planned_path import PlannedPath
from nurbsmotion.planning.measure import measure

HELP = "run every interpolation algorithm on a program and compare the measured figures"

COLUMNS = (("algorithm", "{}"), ("cycles", "{:d}"), ("motion s", "{:.3f}"), ("planning ms", "{:.1f}"),
           ("max chord um", "{:.4f}"), ("min chord um", "{:.2e}"), ("max accel mm/s2", "{:.1f}"),
           ("max jerk mm/s3", "{:.3g}"), ("max fluctuation", "{:.2e}"), ("end error mm", "{:.1e}"))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_planning_arguments(parser)
    parser.add_argument("--algorithms", metavar="A,B,...", default=",".join(ALGORITHM_MODULES),
                        help=f"comma-separated algorithm names (default: {','.join(ALGORITHM_MODULES)})")


def algorithm_names(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise InputError("--algorithms", "no algorithm named")
    for name in names:
        if name not in ALGORITHM_MODULES:
            raise InputError("--algorithms", f"unknown algorithm {name!r}; choose from {', '.join(ALGORITHM_MODULES)}")
    return names


def format_table(rows: list[dict], skipped: dict[str, str]) -> str:
    header = [name for name, _ in COLUMNS]
    cells = [[fmt.format(row[name]) for name, fmt in COLUMNS] for row in rows]
    widths = [max(len(h), *(len(c[i]) for c in cells)) if cells else len(h) for i, h in enumerate(header)]
    lines = ["  ".join(h.rjust(w) for h, w in zip(header, widths))]
    lines += ["  ".join(c.rjust(w) for c, w in zip(cell, widths)) for cell in cells]
    lines += [f"{name}: skipped ({why})" for name, why in skipped.items()]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    names = algorithm_names(args.algorithms)
    program, limits, _ = planning_setup(args)
    rows, skipped = [], {}
    for name in names:
        try:
            plan_fn = planner(name)
        except InputError as err:
            skipped[name] = err.message
            continue
        trajectory = plan_fn(program, limits)
        path = PlannedPath.for_algorithm(program, limits, name)  # lookahead blends corners
        m = measure(path.rows(trajectory), path.program)
        rows.append({"algorithm": name, "cycles": m.cycles, "motion s": m.duration_s,
                     "planning ms": trajectory.planning_time_s * 1000.0,
                     "max chord um": m.max_chord_error_mm * 1000.0, "min chord um": m.min_chord_error_mm * 1000.0,
                     "max accel mm/s2": m.max_accel_mm_s2, "max jerk mm/s3": m.max_jerk_mm_s3,
                     "max fluctuation": m.max_fluctuation, "end error mm": m.end_error_mm,
                     "measured": m.summary(), "planning_time_s": trajectory.planning_time_s})
    if args.json:
        print(json.dumps({"program": program.name, "limits": limits_summary(limits),
                          "results": [{"algorithm": r["algorithm"], "planning_time_s": r["planning_time_s"],
                                       "measured": r["measured"]} for r in rows],
                          "skipped": skipped}, indent=2))
    else:
        print(f"{program.name}: {len(program.blocks)} blocks, {program.length_mm:.3f} mm; "
              f"T {limits.period_s * 1000:g} ms, chord error <= {limits.chord_error_mm:g} mm, "
              f"acceleration <= {limits.max_accel_mm_s2:g} mm/s^2 (figures measured on the set-points)")
        print(format_table(rows, skipped))
    sys.stdout.flush()
    return 0 if rows else 2
