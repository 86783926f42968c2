"""``nurbsmotion programs add FILE [--name NAME] | list | show NAME | remove NAME``: the
daemon's program library (docs/daemon.md, "Program library").

``add`` sends the file's text; the daemon reads and checks it as a job started now would be
and keeps it only when it passes (a refused program: one line per error, file:line, exit 2).
``nurbsmotion start NAME`` then starts it without a second check. Exit codes: 0 done,
2 refused (bad program, bad name, unknown program), 3 no daemon.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from nurbsmotion.cli._control import add_socket_arguments, with_client
from nurbsmotion.cli._format import figure, reading_text
from nurbsmotion.service.client import Client, RequestFailed

HELP = "the daemon's program library: add FILE (checked once), list, show NAME, remove NAME"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True, parser_class=type(parser))
    add = actions.add_parser("add", help="read FILE, have the daemon check it and keep it in the library")
    add.add_argument("file", help="program file (.nc G-code or .yaml curves)")
    add.add_argument("--name", help="its name in the library (default: the file's name)")
    listing = actions.add_parser("list", help="the programs in the library")
    listing.add_argument("--json", action="store_true", help="print the response as JSON")
    show = actions.add_parser("show", help="one program's check: blocks, lines, extent")
    show.add_argument("name")
    show.add_argument("--text", action="store_true", help="print the program's text instead")
    remove = actions.add_parser("remove", help="remove a program from the library")
    remove.add_argument("name")
    for sub in (add, listing, show, remove):
        add_socket_arguments(sub)


def extent_text(extent: dict[str, Any] | None) -> str:
    """'X 0..4 Y 0..3 Z 0..0 mm' (the box holding the path, machine axes)."""
    if not extent:
        return "-"
    return " ".join(f"{axis} {low:g}..{high:g}" for axis, low, high in
                    zip(extent["axes"], extent["min_mm"], extent["max_mm"])) + " mm"


def program_line(meta: dict[str, Any]) -> str:
    check = meta.get("check") or {}
    return (f"{meta['name']}: {figure(check.get('blocks'))} blocks, lines {reading_text(check.get('lines')) or '-'}, "
            f"extent {extent_text(check.get('extent'))}")


def list_lines(response: dict[str, Any]) -> list[str]:
    rows = response["programs"]
    if not rows:
        return ["the library is empty (nurbsmotion programs add FILE)"]
    lines = [f"{'name':28}  {'size':>10}  {'blocks':>8}  added"]
    lines += [f"{r['name'][:28]:28}  {r['size_bytes']:>10}  {figure((r.get('check') or {}).get('blocks')):>8}  "
              f"{r['added_at']}" for r in rows]
    return lines


def run(args: argparse.Namespace) -> int:
    if args.action == "add":
        from nurbsmotion.cli.run import program_request
        from nurbsmotion.text_files import open_text_file

        added = open_text_file(args.file)  # the same errors as check's and run's
        name = args.name or Path(args.file).name

    def body(client: Client) -> int:
        if args.action == "add":
            response = program_request(client, "programs.add", {"name": name}, added)
            if not response.get("ok"):
                raise RequestFailed(response)
            print(f"added {program_line(response['program'])}")
        elif args.action == "list":
            response = client.call("programs.list")
            print(json.dumps(response, indent=2) if args.json else "\n".join(list_lines(response)))
        elif args.action == "show":
            program = client.call("programs.get", name=args.name)["program"]
            print(program["text"], end="") if args.text else print(program_line(program))
        else:
            client.call("programs.remove", name=args.name)
            print(f"removed {args.name}")
        return 0

    try:
        return with_client(args, body)
    finally:
        if args.action == "add":
            added.close()
