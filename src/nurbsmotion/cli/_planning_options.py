"""Options shared by ``plan`` and ``compare``: program, machine config, limit overrides.

PlanLimits come from the machine configuration's ``interpolation`` section and axes; without
``--config``, from the defaults of that section (config.InterpolationConfig: what the daemon
plans with when a configuration sets none, the jerk limit included). Each CLI option
overrides its field; ``--no-jerk-limit`` removes the jerk limit. Every bad value is one line
naming the option (exit 2).
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace

from nurbsmotion.config import InterpolationConfig, MachineConfig, load_config
from nurbsmotion.errors import InputError
from nurbsmotion.planning import PlanLimits, algorithm
from nurbsmotion.planning.limits import interpolation_limits, limits_from_config
from nurbsmotion.program import Program, ReadOptions, load_tool_table, read_program


def positive_number(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def add_planning_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("program", help="G-code (.nc .ngc .gcode .tap) or YAML curve file (.yaml .yml)")
    parser.add_argument("--config", metavar="FILE", help="machine configuration (YAML): interpolation defaults, axis limits")
    parser.add_argument("--start", nargs=3, type=float, metavar=("X", "Y", "Z"), default=(0.0, 0.0, 0.0),
                        help="machine position (mm) a G-code program starts from (default 0 0 0)")
    parser.add_argument("--period-ms", type=positive_number, metavar="T", help="interpolation period T in ms")
    parser.add_argument("--feed-mm-min", type=positive_number, metavar="F", help="feed for every block (overrides the program's F)")
    parser.add_argument("--chord-error-mm", type=positive_number, metavar="D", help="largest chord error δ_max in mm")
    parser.add_argument("--max-accel-mm-s2", type=positive_number, metavar="A", help="largest resultant acceleration")
    jerk = parser.add_mutually_exclusive_group()
    jerk.add_argument("--max-jerk-mm-s3", type=positive_number, metavar="J",
                      help=f"largest jerk (planners that use it; default the config's, else "
                           f"{InterpolationConfig().max_jerk_mm_s3:g})")
    jerk.add_argument("--no-jerk-limit", action="store_true", help="plan without a jerk limit")
    parser.add_argument("--acc-time-s", type=positive_number, metavar="TL", help="linear acc/dec time t_l (a_l = V0 / t_l)")
    parser.add_argument("--json", action="store_true", help="machine-readable output on stdout")


def planning_setup(args: argparse.Namespace) -> tuple[Program, PlanLimits, str]:
    """(program, limits, default algorithm name) from the parsed options."""
    config = load_config(args.config) if args.config else None
    interpolation = config.interpolation if config else InterpolationConfig()
    limits = limits_from_config(config) if config else interpolation_limits(interpolation)
    if args.no_jerk_limit:
        limits = replace(limits, max_jerk_mm_s3=None)
    overrides = {
        "period_s": args.period_ms / 1000.0 if args.period_ms else None,
        "feed_mm_s": args.feed_mm_min / 60.0 if args.feed_mm_min else None,
        "chord_error_mm": args.chord_error_mm,
        "max_accel_mm_s2": args.max_accel_mm_s2,
        "max_jerk_mm_s3": args.max_jerk_mm_s3,
        "acc_time_s": args.acc_time_s,
    }
    options = {"period_s": "--period-ms", "feed_mm_s": "--feed-mm-min", "chord_error_mm": "--chord-error-mm",
               "max_accel_mm_s2": "--max-accel-mm-s2", "max_jerk_mm_s3": "--max-jerk-mm-s3", "acc_time_s": "--acc-time-s"}
    try:
        limits = replace(limits, **{k: v for k, v in overrides.items() if v is not None})
    except InputError as err:
        raise InputError(options.get(err.where, err.where), err.message) from None
    program = read_program(args.program, args.start, machine_read_options(config))
    return program, limits, interpolation.algorithm


def machine_read_options(config: MachineConfig | None, tool_table: str | None = None, block_delete: bool = True,
                         optional_stop: bool = True) -> ReadOptions:
    """What the daemon's reader would start from on this machine: the persisted offsets and
    tool (DATA_DIR/offsets.json), the configured tool table (``tool_table``, a file, wins)."""
    from nurbsmotion.service.machine_state import MachineState, load_state

    state = load_state(config.data_dir) if config is not None else MachineState()
    table = load_tool_table(tool_table) if tool_table else (config.tool_table if config is not None else None)
    return state.read_options(table, block_delete, optional_stop)


def limits_summary(limits: PlanLimits) -> dict[str, float | None]:
    return {"period_ms": limits.period_s * 1000.0, "feed_mm_s": limits.feed_mm_s,
            "chord_error_mm": limits.chord_error_mm, "max_accel_mm_s2": limits.max_accel_mm_s2,
            "max_jerk_mm_s3": limits.max_jerk_mm_s3, "acc_time_s": limits.acc_time_s}


def planner(name: str):
    """The planning function for ``name``: InputError naming --algorithm when unknown or not installed."""
    try:
        return algorithm(name)
    except InputError as err:
        raise InputError("--algorithm", err.message) from None
    except ImportError as err:
        raise InputError("--algorithm", f"{name!r} is not available in this installation ({err})") from None
