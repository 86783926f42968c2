"""The bus side of ``nurbsmotion drives``: ``scan`` and ``check --live`` (cli/drives.py parses)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import canopen

from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import InputError
from nurbsmotion.fieldbus import eds_catalog, live_check
from nurbsmotion.fieldbus.bringup_plan import DrivePlan
from nurbsmotion.fieldbus.scan import VENDOR_NAMES, NodeReport, ScanResult, ScanSettings, nmt_state_name, \
    open_network, scan_network, supported_modes

EXIT_OK, EXIT_FAILED = 0, 1
COLUMNS = ("node", "NMT", "device type", "vendor", "product", "revision", "name", "hw", "sw", "modes", "heartbeat",
           "answer")


def _settings(args: argparse.Namespace, sdo_timeout_ms: int) -> ScanSettings:
    return ScanSettings(listen_s=args.listen_ms / 1000, sdo_timeout_s=sdo_timeout_ms / 1000)


def _open(interface: str, channel: str, bitrate: int, place: str) -> canopen.Network:
    try:
        return open_network(interface, channel, bitrate)
    except Exception as err:  # noqa: BLE001 - python-can raises OSError, CanError, ValueError, ImportError ...
        text = " ".join(str(err).split()) or type(err).__name__
        raise InputError(place, f"cannot open {interface} {channel}: {text}") from None


def _vendor(report: NodeReport, names: dict[int, str]) -> str:
    ident = report.identity
    if ident is None:
        return "-"
    name = names.get(ident.vendor_id)
    return f"0x{ident.vendor_id:08X} {name}" if name else f"0x{ident.vendor_id:08X}"


def _hex(value: int | None) -> str:
    return "-" if value is None else f"0x{value:08X}"


def table_rows(reports: list[NodeReport], names: dict[int, str]) -> list[tuple[str, ...]]:
    """One row of COLUMNS per node."""
    rows: list[tuple[str, ...]] = []
    for r in reports:
        ident = r.identity
        device = f"0x{r.device_type.raw:08X} {r.device_type.describe()}" if r.device_type else "-"
        modes = " ".join(supported_modes(r.modes)) if r.modes is not None else "-"
        rows.append((str(r.node_id), nmt_state_name(r.nmt_state), device, _vendor(r, names),
                     _hex(ident.product_code if ident else None), _hex(ident.revision if ident else None),
                     r.device_name or "-", r.hardware_version or "-", r.software_version or "-", modes,
                     f"{r.heartbeat_period_s * 1000:.0f} ms" if r.heartbeat_period_s else "-", r.status()))
    return rows


def format_table(rows: list[tuple[str, ...]]) -> list[str]:
    widths = [max(len(row[i]) for row in [COLUMNS, *rows]) for i in range(len(COLUMNS))]
    return ["  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip() for row in [COLUMNS, *rows]]


def _catalog(folder: str | None) -> tuple[list[eds_catalog.EdsEntry], list[str]]:
    if folder is None:
        return [], []
    path = Path(folder)
    if not path.is_dir():
        raise InputError(f"--eds-dir {folder}", "not a folder")
    entries, problems = eds_catalog.read_catalog(path)
    if not entries:
        raise InputError(f"--eds-dir {folder}", "holds no readable *.eds / *.dcf file")
    return entries, problems


def _scan(network: canopen.Network, settings: ScanSettings) -> ScanResult:
    try:
        return scan_network(network, settings)
    finally:
        network.disconnect()


def run_scan(args: argparse.Namespace) -> int:
    out_path = Path(args.write_config) if args.write_config else None
    if out_path is not None and out_path.exists():
        raise InputError(f"--write-config {out_path}", "exists already: choose another name (nothing was written)")
    if out_path is not None and not out_path.parent.is_dir():
        raise InputError(f"--write-config {out_path}", f"folder {str(out_path.parent)!r} does not exist")
    catalog, problems = _catalog(args.eds_dir)
    settings = _settings(args, args.sdo_timeout_ms)
    result = _scan(_open(args.interface, args.channel, args.bitrate, f"--channel {args.channel}"), settings)
    for problem in problems:
        print(f"note: {problem}")
    where = (f"{args.interface} {args.channel} within {result.duration_s:.1f} s (heartbeats listened for "
             f"{settings.listen_s:g} s, 0x1000 of nodes 1-127 read with a {settings.sdo_timeout_s * 1000:g} ms "
             "SDO time-out)")
    if not result.reports:
        sys.stderr.write(f"nurbsmotion drives scan: no node found on {where}: check power, wiring, termination "
                         "and bitrate (docs/commissioning.md)\n")
        return EXIT_FAILED
    names = {**VENDOR_NAMES, **eds_catalog.vendor_names(catalog)}
    print("\n".join(format_table(table_rows(result.reports, names))))
    for report in result.reports:
        for problem in report.problems:
            print(f"node {report.node_id}: {problem}")
    matches = {r.node_id: eds_catalog.match(r.identity, catalog) for r in result.reports
               if r.answered_sdo and args.eds_dir}
    if args.eds_dir:
        for node_id, found in matches.items():
            if found.entry is None:
                print(f"node {node_id}: no EDS in {args.eds_dir}: {found.note}")
            else:
                note = f" ({found.note})" if found.note else ""
                print(f"node {node_id}: EDS {found.entry.path} ({found.entry.product_name or 'no ProductName'}){note}")
    print(f"{len(result.reports)} node(s) found on {where}")
    if out_path is not None:
        _write_config(out_path, result.reports, matches, args)
    return EXIT_OK


def _write_config(out_path: Path, reports: list[NodeReport], matches: dict[int, eds_catalog.EdsMatch],
                  args: argparse.Namespace) -> None:
    from nurbsmotion.cli._starting_config import BusSettings, starting_config

    stamp = time.strftime("on %Y-%m-%d %H:%M UTC", time.gmtime())
    text = starting_config(reports, matches, BusSettings(args.interface, args.channel, args.bitrate), out_path, stamp)
    try:
        with out_path.open("x", encoding="utf-8") as out:  # never over a file that appeared meanwhile
            out.write(text)
    except OSError as err:
        raise InputError(f"--write-config {out_path}", f"cannot write: {err.strerror or err}") from None
    print(f"wrote {out_path}: replace every FILL_IN and check every CHECK, then "
          f"`nurbsmotion drives check --config {out_path} --live`")


def run_live_check(args: argparse.Namespace, config: MachineConfig, plans: list[DrivePlan]) -> int:
    """Compare the configuration's bus with the configuration (fieldbus/live_check.py)."""
    bus = config.bus
    if config.simulate:
        raise InputError(config.where("simulate"), "true: the drives run inside the daemon, there is no bus to "
                                                   "check (--live is for real drives, or `nurbsmotion sim`'s)")
    settings = _settings(args, args.sdo_timeout_ms or bus.sdo_timeout_ms)
    expected = live_check.expected_nodes(config, plans)
    network = _open(bus.interface, bus.channel, bus.bitrate, config.where("bus.channel"))
    try:
        result = scan_network(network, settings)
        reports = {r.node_id: r for r in result.reports}
        findings = []
        for node in expected:
            found = live_check.compare(node, reports.get(node.node_id))
            report = reports.get(node.node_id)
            if node.pdos and report is not None and report.answered_sdo:
                found += live_check.read_pdo_capacity(network, node.node_id, node.pdos, node.where, settings)
            findings += found
            if not any(f.error for f in found):
                print(f"live    {node.where}: OK")
        findings += live_check.extra_nodes(expected, result.reports, config.master.node_id)
    finally:
        network.disconnect()
    for finding in findings:
        if not finding.error:
            print(f"warning: {finding.text}")
    errors = [f.text for f in findings if f.error]
    for text in errors:
        sys.stderr.write(f"nurbsmotion drives: error: {text}\n")
    print(f"live check of {bus.interface} {bus.channel}: {len(expected)} configured node(s), "
          f"{len(result.reports)} on the bus, {len(errors)} error(s) ({result.duration_s:.1f} s)")
    return EXIT_FAILED if errors else EXIT_OK
