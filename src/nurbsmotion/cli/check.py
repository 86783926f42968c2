"""``nurbsmotion check PROGRAM``: read and validate a program, print what it does.

Exit 0 with a summary (blocks by kind, length, bounding box of the sampled path, feed
range, events between moves), or exit 2 with one line per error (``file:line: word:
message``): every problem of the file, in line order, up to 50. With ``--config`` the
program is also planned for that machine exactly as the daemon's ``submit`` does: its axes,
limits and soft limits apply (``part.nc:42: X650: axis X would reach 650 mm, beyond the
soft limit 600 mm``), the program starts from the daemon's persisted offsets and the
configured tool table, and what the machine lacks is refused (``part.nc:7: M3 needs a
spindle, and this machine has none``; M0/M1/M6: the daemon cannot hold a job yet).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TypedDict

from nurbsmotion.errors import InputError
from nurbsmotion.cli._format import reading_text
from nurbsmotion.cli._planning_options import machine_read_options
from nurbsmotion.config import MachineConfig, load_config
from nurbsmotion.program import ReadOptions, read_program
from nurbsmotion.program.summary import ProgramSummary, summarize

HELP = "validate a G-code or YAML curve program and summarise it"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("program", help="G-code (.nc .ngc .gcode .tap) or YAML curve file (.yaml .yml)")
    parser.add_argument("--json", action="store_true", help="machine-readable output on stdout")
    parser.add_argument("--start", nargs=3, type=float, metavar=("X", "Y", "Z"), default=(0.0, 0.0, 0.0),
                        help="machine position (mm) the G-code program starts from (default 0 0 0)")
    parser.add_argument("--tool-table", metavar="YAML", help="tool table for T, M6 and G43 H (docs/programs.md)")
    parser.add_argument("--no-block-delete", action="store_true", help="run '/' lines (block delete switch off)")
    parser.add_argument("--no-optional-stop", action="store_true", help="M1 does not pause (optional stop switch off)")
    parser.add_argument("--config", metavar="FILE", help="machine configuration: also plan the program for it and "
                                                         "check its axes, limits and soft limits as submit does")


class MachineCheck(TypedDict):
    """What ``check --config`` adds: the machine and the plan's length on it."""

    config: str
    axes: list[str]
    cycles: int
    duration_s: float
    algorithm: str


def check_on_machine(args: argparse.Namespace, config: MachineConfig, options: ReadOptions) -> MachineCheck:
    """Plan the program for the ``--config`` machine (service.planner.plan_job, the daemon's
    own checks: spindle, coolant, holds, limits); InputError names the program line."""
    import numpy as np

    from nurbsmotion.service.job_common import axis_columns
    from nurbsmotion.service.planner import plan_job

    start_mm = np.array(args.start, dtype=float)[axis_columns(config)]
    text = Path(args.program).read_text(encoding="utf-8-sig")  # read_program read it already: it is readable
    plan = plan_job(args.program, text, config, start_mm, options).summary
    return {"config": str(args.config), "axes": [a.name for a in config.axes], "cycles": plan["cycles"],
            "duration_s": plan["duration_s"], "algorithm": plan["algorithm"]}


def format_summary(s: ProgramSummary) -> str:
    def xyz(v: tuple[float, float, float]) -> str:
        return " ".join(f"{a}{c:.3f}" for a, c in zip("XYZ", v))

    kinds = ", ".join(f"{n} {k}" for k, n in sorted(s.blocks_by_kind.items())) or "none"
    lengths = ", ".join(f"{k} {v:.3f}" for k, v in sorted(s.length_by_kind_mm.items()))
    if s.feed_min_mm_min is None:
        feeds = "machine default for every block"
    else:
        feeds = f"{s.feed_min_mm_min:g} .. {s.feed_max_mm_min:g} mm/min"
        if s.blocks_at_machine_feed:
            feeds += f" ({s.blocks_at_machine_feed} blocks at the machine's rapid/default feed)"
    read = reading_text(s.reading)
    lines = [
        f"program   {s.name}: OK",
        *([f"lines     {read}"] if read else []),
        f"blocks    {s.blocks} ({kinds})",
        f"length    {s.length_mm:.3f} mm" + (f" ({lengths})" if lengths else ""),
        f"start     {xyz(s.start_mm)}",
        f"end       {xyz(s.end_mm)}",
        f"bbox min  {xyz(s.bbox_min_mm)}",
        f"bbox max  {xyz(s.bbox_max_mm)}",
        f"feed      {feeds}",
    ]
    if s.events_by_kind:
        events = ", ".join(f"{n} {k}" for k, n in sorted(s.events_by_kind.items()))
        lines.append(f"events    {events}" + (f"; dwell {s.dwell_s:g} s" if s.dwell_s else "")
                     + (f"; tools {' '.join(f'T{t}' for t in s.tools)}" if s.tools else ""))
    needs = [name for name, needed in (("spindle", s.requires_spindle), ("coolant", s.requires_coolant)) if needed]
    if needs:
        lines.append(f"needs     {' and '.join(needs)}")
    return "\n".join(lines)


def errors_as_json(err: InputError) -> str:
    errors = getattr(err, "errors", [err])
    return json.dumps({"ok": False, "errors": [{"where": e.where, "message": e.message} for e in errors]}, indent=2)


def run(args: argparse.Namespace) -> int:
    try:
        config = load_config(args.config) if args.config else None
        options = machine_read_options(config, args.tool_table, not args.no_block_delete, not args.no_optional_stop)
        program = read_program(args.program, args.start, options)
    except InputError as err:
        if not args.json:
            raise
        print(errors_as_json(err))
        return 2
    summary = summarize(program)
    try:
        machine = check_on_machine(args, config, options) if config is not None else None
    except InputError as err:
        if not args.json:
            raise
        print(errors_as_json(err))
        return 2
    if args.json:
        print(json.dumps({"ok": True, **summary.as_dict(), **({"machine": machine} if machine else {})}, indent=2))
    else:
        print(format_summary(summary))
        if machine:
            print(f"machine   {machine['config']}: axes {' '.join(machine['axes'])}, within the axis and soft "
                  f"limits ({machine['algorithm']}: {machine['cycles']} cycles, {machine['duration_s']:.2f} s)")
    sys.stdout.flush()
    return 0
