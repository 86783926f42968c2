"""``nurbsmotion queue add NAME [--start-line N] | list | remove ID | move ID POS | clear |
pause | resume``: the daemon's persistent job queue of library programs (docs/daemon.md,
"Job queue"). They run one after another while the machine is idle; a job that does not
complete, a refused start and a daemon restart pause the queue until ``queue resume``.
Exit codes: 0 done, 2 refused (unknown program or entry), 3 no daemon.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from nurbsmotion.cli._control import add_socket_arguments, with_client
from nurbsmotion.service.client import Client

HELP = "the daemon's job queue of library programs: add NAME, list, remove ID, move ID POS, clear, pause, resume"
ACTIONS = ("add", "list", "remove", "move", "clear", "pause", "resume")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from nurbsmotion.cli.run import line_number

    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True, parser_class=type(parser))
    subs = {
        "add": actions.add_parser("add", help="queue a library program (nurbsmotion programs list)"),
        "list": actions.add_parser("list", help="the queue's entries in order, and whether it is paused"),
        "remove": actions.add_parser("remove", help="take an entry out of the queue"),
        "move": actions.add_parser("move", help="put an entry at a position (1 = next)"),
        "clear": actions.add_parser("clear", help="remove every entry"),
        "pause": actions.add_parser("pause", help="start no more entries (the running job goes on)"),
        "resume": actions.add_parser("resume", help="start the entries again when the machine is idle"),
    }
    subs["add"].add_argument("name")
    subs["add"].add_argument("--start-line", type=line_number, metavar="N", help="start the program from line N")
    subs["list"].add_argument("--json", action="store_true", help="print the response as JSON")
    subs["remove"].add_argument("id", type=int)
    subs["move"].add_argument("id", type=int)
    subs["move"].add_argument("position", type=int, help="1 = the next to run")
    for sub in subs.values():
        add_socket_arguments(sub)


def queue_lines(queue: dict[str, Any]) -> list[str]:
    state = f"paused: {queue['paused']}" if queue["paused"] else "running when the machine is idle"
    lines = [f"queue {state}"]
    if not queue["entries"]:
        return lines + ["(empty: nurbsmotion queue add NAME)"]
    lines += [f"{i:>3}. id {e['id']:<5} {e['program']}"
              f"{' from line ' + str(e['start_line']) if e['start_line'] else ''}  (added {e['added_at']})"
              for i, e in enumerate(queue["entries"], 1)]
    return lines


def run(args: argparse.Namespace) -> int:
    def body(client: Client) -> int:
        fields: dict[str, Any] = {}
        if args.action == "add":
            fields = {"name": args.name, **({"start_line": args.start_line} if args.start_line else {})}
        elif args.action in ("remove", "move"):
            fields = {"id": args.id, **({"position": args.position} if args.action == "move" else {})}
        response = client.call(f"queue.{args.action}", **fields)
        if args.action == "list" and args.json:
            print(json.dumps(response, indent=2))
        else:
            print("\n".join(queue_lines(response["queue"])))
        return 0

    return with_client(args, body)
