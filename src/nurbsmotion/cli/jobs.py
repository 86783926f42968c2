"""``nurbsmotion jobs [ID]``: the job records (newest first), or one record in full.

Asks the daemon (control API ``jobs`` / ``job``). When no daemon answers and a configuration
is known (``--config`` or ``$NURBSMOTION_CONFIG``), the records are read from its
``data_dir`` directly, so they can be read after the daemon has ended. Exit codes: 0 shown,
2 unknown id or bad option, 3 no daemon (and no configuration to find the records).
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import sys

from nurbsmotion.cli._control import EXIT_NO_DAEMON, add_socket_arguments, config_path, with_client
from nurbsmotion.cli._format import figure, number
from nurbsmotion.cli.status import fault_text
from nurbsmotion.config import load_config
from nurbsmotion.service.client import Client
from nurbsmotion.service.records import JobRecords

HELP = "list the job records (newest first) or show one: outcome, line reached, times, faults, overrides"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("id", nargs="?", help="a job id: show that record")
    parser.add_argument("-n", "--limit", type=int, default=20, help="how many records to list (default 20)")
    parser.add_argument("--json", action="store_true", help="print the response as JSON")
    add_socket_arguments(parser)


def list_lines(response: dict[str, Any]) -> list[str]:
    rows = response["jobs"]
    if not rows:
        return [f"no job records in {response['root']}"]
    lines = [f"{'id':8}  {'submitted':23}  {'outcome':11}  {'time s':>7}  {'program':20}  line reached / reason"]
    for r in rows:
        outcome = "running" if r["running"] else r["outcome"] or "-"
        seconds = number(r["motion_time_s"], 2)
        detail = r["line_reached"] or ""
        if r["outcome"] not in (None, "completed") and r["reason"]:
            detail = f"{detail}: {r['reason']}" if detail else r["reason"]
        lines.append(f"{r['id']:8}  {r['submitted_at'] or '-':23}  {outcome:11}  {seconds:>7}  {r['name'][:20]:20}  {detail}")
    if response["total"] > len(rows):
        lines.append(f"({len(rows)} of {response['total']}; --limit N for more)")
    return lines


def show_lines(job: dict[str, Any]) -> list[str]:
    outcome, plan = job.get("outcome") or {}, job.get("plan") or {}
    lines = [f"job {job['id']}  {outcome.get('name') or plan.get('program', '')}",
             f"folder      {job['folder']}",
             f"outcome     {'running' if job['running'] else outcome.get('outcome', '-')}"
             f"{': ' + outcome['reason'] if outcome.get('reason') else ''}"]
    for error in outcome.get("errors") or []:
        lines.append(f"error       {error}")
    if plan:
        lines.append(f"plan        {plan.get('blocks')} blocks, {number(plan.get('length_mm'), 3)} mm, "
                     f"{plan.get('cycles') if plan.get('cycles') is not None else '-'} cycles, "
                     f"{number(plan.get('duration_s'), 3)} s ({plan.get('algorithm')})")
    if outcome.get("started_at"):
        lines.append(f"time        {outcome['started_at']} .. {outcome.get('ended_at', '')} "
                     f"({number(outcome.get('motion_time_s'), 2)} s)")
        lines.append(f"set-points  {figure(outcome.get('sent'))}/{figure(outcome.get('planned'))} sent; "
                     f"{figure(outcome.get('late_cycles'))} late, {figure(outcome.get('missed_cycles'))} missed cycles")
    reached = outcome.get("line_reached")
    if reached:
        lines.append(f"reached     {reached['where']}: {reached['text']}")
    for name, pos in (outcome.get("final_position") or {}).items():
        lines.append(f"final {name:5} commanded {number(pos['commanded_mm'], 4)} mm, "
                     f"actual {number(pos['actual_mm'], 4)} mm")
    for o in outcome.get("overrides") or []:
        lines.append(f"override    {number(o['at_s'], 3)} s (set-point {o['setpoint']}): "
                     f"{figure(o['requested_percent'], 'g')} % requested, "
                     f"{figure(o['effective_percent'], 'g')} % effective ({o['by']})")
    for fault in outcome.get("faults") or []:
        lines.append(f"fault       {fault_text(fault)}")
    lines.append(f"files       {' '.join(job.get('files') or [])}")
    return lines


def show(args: argparse.Namespace, response: dict[str, Any]) -> int:
    if args.json:
        print(json.dumps(response, indent=2))
    else:
        print("\n".join(show_lines(response["job"]) if args.id else list_lines(response)))
    return 0


def read_here(args: argparse.Namespace) -> int:
    """The records read from the configuration's data_dir (no daemon answered)."""
    records = JobRecords(load_config(config_path(args)).data_dir)  # type: ignore[arg-type]
    response = {"ok": True, "job": records.info(args.id)} if args.id else {"ok": True, **records.listing(args.limit)}
    sys.stderr.write(f"nurbsmotion jobs: no daemon answers; read from {records.root}\n")
    return show(args, response)


def run(args: argparse.Namespace) -> int:
    def body(client: Client) -> int:
        return show(args, client.call("job", id=args.id) if args.id else client.call("jobs", limit=args.limit))

    code = with_client(args, body, quiet_no_daemon=config_path(args) is not None and not args.socket)
    return read_here(args) if code == EXIT_NO_DAEMON and config_path(args) and not args.socket else code
