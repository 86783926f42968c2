"""``nurbsmotion drives check --config FILE [--live]`` and ``nurbsmotion drives scan``.

``check``: per axis, what bring-up will write to the drive and whether its EDS allows it,
without touching the bus. Exit 0 when every axis can be brought up; exit 2 with one line per
refused axis (``config.yaml:31: axes[0] (X, node 1): epos2.eds has no 0x60C1:01, so ...``).
With ``--live`` it then reads the configuration's bus and compares each configured node with
it (fieldbus/live_check.py): exit 1 with one ``error:`` line per mismatch.

``scan``: every node on a bus, what it is, the EDS that describes it, and a starting
configuration (fieldbus/scan.py, docs/commissioning.md). Exit 0 when at least one node was
found, 1 when none was, 2 for bad arguments (also a bus that cannot be opened, an unreadable
``--eds-dir``, an existing ``--write-config`` file: nothing is sent or written then).
"""

from __future__ import annotations

import argparse

from nurbsmotion.axes import AxisMap
from nurbsmotion.config import MachineConfig, load_config
from nurbsmotion.errors import InputError, InputErrors
from nurbsmotion.fieldbus.bringup_plan import MODE_WORDS, DrivePlan, PdoFrame, PdoSetup, ReadBack, Write, \
    cyclic_load, describe_value, plan_drive, plan_within_load
from nurbsmotion.fieldbus.busload import fits_following_error_tpdo

HELP = "find and identify the drives on a bus (scan), check them against the configuration (check, --live)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="drives_command", metavar="ACTION", required=True, parser_class=type(parser))
    check = sub.add_parser("check", help="print each axis' bring-up plan; exit 2 if a drive cannot do it")
    check.add_argument("--config", required=True, help="machine configuration (YAML)")
    check.add_argument("--live", action="store_true",
                       help="then read the configuration's bus and compare every configured node with it "
                            "(identity, profile, 0x6502, PDO capacity); only SDO reads, never while the daemon runs")
    _add_timing(check, sdo_default=None)
    scan = sub.add_parser("scan", help="find every node on a bus, say what it is and which EDS describes it")
    scan.add_argument("--interface", default="socketcan", help="python-can interface (default socketcan)")
    scan.add_argument("--channel", default="can0", help="bus channel (default can0)")
    scan.add_argument("--bitrate", type=_positive_int, default=1_000_000,
                      help="bit/s, for interfaces that set it (SocketCAN: ip link sets it) and the written "
                           "configuration (default 1000000)")
    scan.add_argument("--eds-dir", help="folder of EDS/DCF files: say which one matches each node (0x1018)")
    scan.add_argument("--write-config", metavar="FILE",
                      help="write a starting configuration (axes, identities, EDS paths); it must not exist yet")
    _add_timing(scan, sdo_default=100)


def _positive_int(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {value}")
    return value


def _add_timing(parser: argparse.ArgumentParser, sdo_default: int | None) -> None:
    parser.add_argument("--listen-ms", type=_positive_int, default=1000,
                        help="listen for boot-up/heartbeat frames this long before the SDO reads (default 1000)")
    parser.add_argument("--sdo-timeout-ms", type=_positive_int, default=sdo_default,
                        help="time-out of one SDO answer; all ids 1-127 are probed at once, so an empty bus costs "
                             "one time-out" + (f" (default {sdo_default})" if sdo_default else
                                               " (default: the configuration's bus.sdo_timeout_ms)"))


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
    if args.drives_command == "scan":
        from nurbsmotion.cli._drives_scan import run_scan
        return run_scan(args)
    config, plans = _check_offline(args.config)
    if not args.live:
        return 0
    from nurbsmotion.cli._drives_scan import run_live_check
    return run_live_check(args, config, plans)


def _check_offline(path: str) -> tuple[MachineConfig, list[DrivePlan]]:
    config = load_config(path)
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
    return config, plans
