"""``nurbsmotion drives check --config FILE``: per axis, what bring-up will write to the drive
and whether its EDS allows it, without touching the bus.

Exit 0 when every axis can be brought up; exit 2 with one line per refused axis
(``config.yaml:31: axes[0] (X, node 1): epos2.eds has no 0x60C1:01, so ...``).
"""

from __future__ import annotations

import argparse

from nurbsmotion.axes import AxisMap
from nurbsmotion.config import load_config
from nurbsmotion.errors import InputError, InputErrors
from nurbsmotion.fieldbus.bringup_plan import MODE_WORDS, DrivePlan, PdoFrame, PdoSetup, ReadBack, Write, \
    cyclic_load, describe_value, plan_drive, plan_within_load
from nurbsmotion.fieldbus.busload import fits_following_error_tpdo

HELP = "check the drives' descriptions (EDS) against the configuration: what bring-up writes"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="drives_command", metavar="ACTION", required=True, parser_class=type(parser))
    check = sub.add_parser("check", help="print each axis' bring-up plan; exit 2 if a drive cannot do it")
    check.add_argument("--config", required=True, help="machine configuration (YAML)")


def _frame(frame: PdoFrame) -> str:
    fields = " + ".join(f"{f.name.lower().replace('_', ' ')} 0x{f.index:04X}:{f.subindex:02X}" for f in frame.fields)
    return f"{frame.kind}{frame.number} (COB-ID 0x{frame.cob_id:03X}, {frame.dlc} bytes): {fields}"


def format_plan(plan: DrivePlan, od: object) -> list[str]:
    lines = [f"axis {plan.axis} (node {plan.node_id}): {plan.eds}, {MODE_WORDS[plan.mode]}: OK"]
    for frame in plan.layout.rpdos + plan.layout.tpdos:
        lines.append(f"  cyclic  {_frame(frame)}")
    if plan.check_supported_modes:
        lines.append("  read    0x6502:00 (supported drive modes) must have the mode's bit")
    for step in plan.steps:
        if isinstance(step, Write):
            why = f"  [{step.why}]" if step.why else ""
            lines.append(f"  write   {describe_value(od, step.index, step.subindex, step.value)}  "  # type: ignore[arg-type]
                         f"- {step.step}{why}")
        elif isinstance(step, ReadBack):
            lines.append(f"  read    0x{step.index:04X}:{step.subindex:02X} must read {step.expect} - {step.step}")
        elif isinstance(step, PdoSetup) and step.frame is not None:
            lines.append(f"  map     {_frame(step.frame)}, transmission type 1 (every SYNC)")
    lines += plan.homing.describe() if plan.homing is not None else []
    for skipped in plan.skipped:
        lines.append(f"  skip    {skipped.what}: {skipped.reason}")
    return lines


def run(args: argparse.Namespace) -> int:
    config = load_config(args.config)
    windows = AxisMap.from_config(config).following_error_window_counts()
    fe_tpdo = fits_following_error_tpdo(config)
    errors: list[InputError] = []
    plans = []
    for i, axis in enumerate(config.axes):
        try:
            plans.append(plan_drive(config, i, int(windows[i]), fe_tpdo))
        except InputError as err:
            errors.append(err)
    if errors:
        for plan in plans:
            print("\n".join(format_plan(plan, config.axes[plan.axis_index].od)))
        raise InputErrors(errors)
    plans = plan_within_load(config, [int(w) for w in windows])  # as bring-up does; InputError if over the limit
    for plan in plans:
        print("\n".join(format_plan(plan, config.axes[plan.axis_index].od)))
    print(f"cyclic bus load {cyclic_load(config, plans):.0%} at {config.cycle_period_s * 1000:g} ms and "
          f"{config.bus.bitrate / 1000:g} kbit/s (limit {config.monitoring.max_bus_load:.0%})")
    return 0
