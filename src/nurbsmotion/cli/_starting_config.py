"""The starting machine configuration ``nurbsmotion drives scan --write-config`` writes.

From what the scan read: one axis per CiA-402 drive that offers CSP or IP (0x6502 bit 7 /
bit 6; CSP preferred), with its node id, its 0x1018 identity and the matching EDS; a
CiA-402 drive offering only velocity modes (pv, csv) becomes the spindle; the first CiA-401
node the ``io`` section. Values only the integrator knows are written ``FILL_IN``: the file
does not load (``load_config`` names each line) until they are replaced. What the scan only
guessed (axis names, mode) is marked ``CHECK``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from nurbsmotion.fieldbus.eds_catalog import EdsMatch
from nurbsmotion.fieldbus.scan import PROFILE_DRIVE, PROFILE_IO, NodeReport, supported_modes

FILL_IN = "FILL_IN"
AXIS_NAMES = ("X", "Y", "Z", "A", "B", "C")
MODE_CSP_BIT, MODE_IP_BIT, MODE_PV_BIT, MODE_CSV_BIT = 7, 6, 2, 8


@dataclass(frozen=True)
class BusSettings:
    interface: str
    channel: str
    bitrate: int


def axis_mode(modes: int | None) -> str | None:
    """``csp`` / ``ip`` from 0x6502 (None: neither bit set); unknown 0x6502 -> ``csp``."""
    if modes is None or modes >> MODE_CSP_BIT & 1:
        return "csp"
    return "ip" if modes >> MODE_IP_BIT & 1 else None


def spindle_mode(modes: int | None) -> str | None:
    if modes is None:
        return None
    if modes >> MODE_CSV_BIT & 1:
        return "csv"
    return "profile_velocity" if modes >> MODE_PV_BIT & 1 else None


def _eds_line(match: EdsMatch | None, out_dir: Path, indent: str) -> str:
    if match is None or match.entry is None:
        why = match.note if match is not None else "no --eds-dir given"
        return f"{indent}eds: {FILL_IN}   # the drive's EDS/DCF file ({why})\n"
    path = match.entry.path.resolve()
    inside = path.is_relative_to(out_dir.resolve())  # relative to the file's folder, as load_config reads it
    shown = str(path.relative_to(out_dir.resolve())) if inside else str(path)
    note = f"; {match.note}" if match.note else ""
    return f"{indent}eds: {shown}   # matched by 0x1018 vendor + product{note}\n"


def _modes_text(report: NodeReport) -> str:
    return " ".join(supported_modes(report.modes)) if report.modes is not None else "0x6502 not readable"


def _axis(name: str, report: NodeReport, mode: str, match: EdsMatch | None, out_dir: Path) -> str:
    ident = report.identity
    lines = [f"  - name: {name}   # CHECK: the axis node {report.node_id} moves (first slow jog, docs/commissioning.md)\n",
             f"    node_id: {report.node_id}\n",
             f"    mode: {mode}   # CHECK: 0x6502 of node {report.node_id}: {_modes_text(report)}\n",
             _eds_line(match, out_dir, "    ")]
    if ident is not None and ident.product_code is not None:
        lines.append(f"    identity: {{vendor_id: 0x{ident.vendor_id:08X}, product_code: 0x{ident.product_code:08X}}}"
                     f"   # 0x1018:01/02 read from node {report.node_id}\n")
    lines += [f"    counts_per_mm: {FILL_IN}   # encoder counts per mm of travel (counts/rev x gear ratio / "
              "screw pitch)\n",
              f"    soft_limits_mm: {FILL_IN}   # [min, max] of the travel in machine mm after homing\n",
              "    max_velocity_mm_s: 100   # CHECK: the axis' top speed\n",
              "    max_accel_mm_s2: 1000    # CHECK\n",
              "    following_error_window_mm: 1.0   # CHECK: 0x6065 (in counts) = this x counts_per_mm\n",
              "    # quick_stop_decel: 0      # 0x6085 in the DRIVE's units (its manual); unset: the drive's value\n",
              "    # homing: {method: 17, speed_search_mm_s: 10, speed_zero_mm_s: 1, accel_mm_s2: 100, offset_mm: 0}\n"]
    return "".join(lines)


def _spindle(report: NodeReport, mode: str, match: EdsMatch | None, out_dir: Path) -> str:
    return "".join([
        f"spindle:   # node {report.node_id}: a CiA 402 drive offering {_modes_text(report)} (no ip/csp)\n",
        f"  node_id: {report.node_id}\n",
        f"  mode: {mode}\n",
        _eds_line(match, out_dir, "  "),
        f"  counts_per_rev: {FILL_IN}   # encoder counts per spindle revolution\n",
        f"  max_rpm: {FILL_IN}\n",
        f"  accel_rpm_s: {FILL_IN}\n",
    ])


def _io(report: NodeReport) -> str:
    kind = report.device_type.describe() if report.device_type else "CiA 401"
    return "".join([
        f"io:   # node {report.node_id}: {kind}\n",
        f"  node_id: {report.node_id}\n",
        "  inputs: {}    # e.g. estop: {bit: 0, active_low: true}, limit_x_min: 1 (docs/machine.md)\n",
        "  outputs: {}   # e.g. coolant_flood: 0\n",
    ])


def starting_config(reports: list[NodeReport], matches: dict[int, EdsMatch], bus: BusSettings, out_path: Path,
                    when: str) -> str:
    """The YAML text (see the module docstring); ``when`` names the scan in the header."""
    out_dir = out_path.parent
    axes: list[str] = []
    skipped: list[str] = []
    spindle = io = ""
    for report in reports:
        profile = report.profile
        match = matches.get(report.node_id)
        if profile == PROFILE_DRIVE and axis_mode(report.modes) and len(axes) < len(AXIS_NAMES):
            axes.append(_axis(AXIS_NAMES[len(axes)], report, axis_mode(report.modes) or "csp", match, out_dir))
        elif profile == PROFILE_DRIVE and spindle_mode(report.modes) and not spindle:
            spindle = _spindle(report, spindle_mode(report.modes) or "csv", match, out_dir)
        elif profile == PROFILE_IO and not io:
            io = _io(report)
        else:
            what = report.device_type.describe() if report.device_type else "no device type read"
            skipped.append(f"# node {report.node_id} ({what}; {report.status()}) is not in this file\n")
    head = [f"# Starting configuration written by `nurbsmotion drives scan` {when}\n",
            f"# from {bus.interface} {bus.channel}: nodes {', '.join(str(r.node_id) for r in reports) or 'none'}.\n",
            f"# It does not load until every {FILL_IN} is replaced (load_config names each line);\n",
            "# check every CHECK, then run `nurbsmotion drives check --config THIS_FILE --live`.\n",
            "# docs/commissioning.md walks through each value.\n",
            "cycle_period_ms: 4\n",
            "bus:\n",
            f"  interface: {bus.interface}\n",
            f"  channel: {bus.channel}\n",
            f"  bitrate: {bus.bitrate}   # CHECK: the interface's bitrate (ip -details link show {bus.channel})\n"]
    body = ["axes:\n", *axes] if axes else ["axes:   # no CiA 402 drive with csp/ip found: add the axes\n",
                                              f"  - {{name: X, node_id: {FILL_IN}}}\n"]
    return "".join(head + body + ([spindle] if spindle else []) + ([io] if io else []) + skipped)
