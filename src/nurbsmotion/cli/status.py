"""``nurbsmotion status``: the daemon's state, job progress, axes, cycle statistics, faults."""

from __future__ import annotations

import argparse
import json
from typing import Any

from nurbsmotion.cli._control import add_socket_arguments, with_client
from nurbsmotion.cli._format import figure, number
from nurbsmotion.service.client import Client

HELP = "show the daemon's state, job progress, positions, following errors and faults"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print the status response as JSON")
    add_socket_arguments(parser)


def format_status(s: dict[str, Any]) -> list[str]:
    """Human-readable lines of a status response."""
    override = s["override"]
    lines = [f"state {s['state']} (drives {s['phase']}), override {figure(override['requested_percent'], 'g')} % "
             f"(effective {figure(override['effective_percent'], 'g')} %)"]
    coords = s.get("coordinates")
    if coords:
        offset = " ".join(f"{a}{figure(v, 'g')}" for a, v in zip("XYZ", coords["active_offset_mm"]))
        g92 = " ".join(f"{a}{figure(v, 'g')}" for a, v in zip("XYZ", coords["g92_mm"])) if coords["g92_applied"] \
            else "off"
        tool = f"T{coords['tool']}" if coords.get("tool") is not None else "unknown"
        lines.append(f"coordinates {coords['active']} (offset {offset} mm), G92 {g92}, tool {tool}")
    job = s.get("job")
    if job:
        started = f" from line {job['start_line']}" if job.get("start_line") else ""
        lines.append(f"job {job['id']} {job['name']}{started}: cycle {job['cycle']}/{job['total']} "
                     f"({number(job['percent'], 1)} %), feed {number(job['feed_mm_s'], 1)} mm/s, "
                     f"override {figure(job['override_percent'], 'g')} %, "
                     f"at {job.get('line') or '-'}")
    homing = s.get("homing") or {"axes": {}}
    for a in s["axes"]:
        homed = homing["axes"].get(a["name"])
        lines.append(f"axis {a['name']} node {a['node']}{f' ({homed})' if homed else ''}: {a['drive_state']}, commanded {number(a['commanded_mm'], 4)} mm, "
                     f"actual {number(a['actual_mm'], 4)} mm, following error {number(a['following_error_mm'], 4)} mm")
    if homing.get("error"):
        lines.append(f"homing failed: {homing['error']}")
    lines.extend(device_lines(s))
    c = s["cycles"]
    lines.append(f"cycles {c['count']}: late {c['late']}, missed {c['missed']}, lateness p99 "
                 f"{number(c['lateness_p99_ms'], 3)} ms, max {number(c['lateness_max_ms'], 3)} ms")
    lines.extend(f"fault: {fault_text(f)}" for f in s["faults"])
    last = s.get("last_job")
    if last:
        reached = f" at {last['line_reached']}" if last.get("line_reached") else ""
        lines.append(f"last job {last['id']} {last['name']}: {last['outcome']}{reached}"
                     f"{': ' + last['reason'] if last.get('reason') else ''}")
    return lines


def device_lines(s: dict[str, Any]) -> list[str]:
    """The spindle (commanded / actual rpm) and machine I/O lines, when configured."""
    lines = []
    sp = s.get("spindle")
    if sp:
        lines.append(f"spindle node {sp['node']}: {sp['drive_state']}, commanded {figure(sp['commanded_rpm'], 'g')} rpm, "
                     f"actual {figure(sp['actual_rpm'], 'g')} rpm{', at speed' if sp['at_speed'] else ''}"
                     f"{', fault: ' + sp['fault'] if sp.get('fault') else ''}")
    io = s.get("io")
    if io:
        active = [n for n, on in (io["inputs"] or {}).items() if on]
        outputs = [n for n, on in io["outputs"].items() if on]
        lines.append(f"io node {io['node']}: inputs active {', '.join(active) or 'none'}"
                     f"{' (unknown)' if io['inputs'] is None else ''}, outputs on {', '.join(outputs) or 'none'}"
                     f"{', LOST: ' + io['lost'] if io.get('lost') else ''}")
    return lines


def fault_text(fault: dict[str, Any]) -> str:
    """The fault's message with its code and measured value, if any."""
    extra = [f"code {fault['code_hex']}"] if fault.get("code_hex") else []
    extra += [f"{k} {figure(v, 'g' if isinstance(v, float) else '')}" for k, v in (fault.get("measured") or {}).items()]
    return fault["message"] + (f" [{', '.join(extra)}]" if extra else "")


def run(args: argparse.Namespace) -> int:
    def body(client: Client) -> int:
        response = client.call("status")
        if args.json:
            print(json.dumps(response, indent=2))
        else:
            print("\n".join(format_status(response)))
        return 0
    return with_client(args, body)
