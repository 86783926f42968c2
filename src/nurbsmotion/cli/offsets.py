"""``nurbsmotion offsets``: show or change the work offsets the daemon keeps between jobs.

``offsets`` shows every system, G92, G28/G30 and the active one; ``offsets G55 X10 Y-5 Z0``
sets G55's offset (machine mm, as ``G10 L2 P2``; axes not given keep their value);
``offsets --clear G92`` clears G92 (as G92.1), ``--clear G55`` zeroes that offset,
``--clear G28``/``G30`` the stored positions; ``--select G55`` makes G55 active for the next
program. Changes are refused while a job runs; the daemon writes them to DATA_DIR/offsets.json.
"""

from __future__ import annotations

import argparse
import json
import re
from typing import Any

from nurbsmotion.cli._control import add_socket_arguments, with_client
from nurbsmotion.cli._format import figure
from nurbsmotion.errors import InputError
from nurbsmotion.service.client import Client

HELP = "show or set the work offsets G54-G59.3, G92 and G28/G30 positions (between jobs)"
_AXIS_WORD = re.compile(r"^([XYZxyz])\s*([-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?)$")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("system", nargs="?", help="work offset to set: G54 ... G59.3")
    parser.add_argument("words", nargs="*", metavar="AXIS", help="X10 Y-5 Z0: the offset per axis in machine mm")
    parser.add_argument("--clear", metavar="NAME", help="zero one: G54 ... G59.3, G92 (as G92.1), G28 or G30")
    parser.add_argument("--select", metavar="SYSTEM", help="make this system active for the next program")
    parser.add_argument("--json", action="store_true", help="print the response as JSON")
    add_socket_arguments(parser)


def request_fields(args: argparse.Namespace) -> dict[str, Any]:
    """The control request's fields; InputError naming the bad word."""
    fields: dict[str, Any] = {}
    if args.system:
        fields["system"] = args.system
        if not args.words:
            raise InputError(args.system, "give the offset per axis, e.g. X10 Y-5 Z0")
    for word in args.words:
        match = _AXIS_WORD.match(word)
        if match is None:
            raise InputError(word, "must be an axis word X, Y or Z with a number in mm, e.g. X10 or Z-2.5")
        axis = match.group(1).lower()
        if axis in fields:
            raise InputError(word, f"axis {axis.upper()} is given twice")
        fields[axis] = float(match.group(2))
    if args.clear:
        fields["clear"] = args.clear
    if args.select:
        fields["select"] = args.select
    return fields


def format_offsets(o: dict[str, Any]) -> list[str]:
    def xyz(v: list[float]) -> str:
        return " ".join(f"{a}{figure(c, 'g')}" for a, c in zip("XYZ", v))

    lines = [f"active {o['active']}, tool {'T' + str(o['tool']) if o.get('tool') is not None else 'unknown'}"]
    for name, value in o["work_offsets_mm"].items():
        lines.append(f"{'*' if name == o['active'] else ' '} {name:<6} {xyz(value)}")
    lines.append(f"  G92    {xyz(o['g92_mm'])} ({'applied' if o['g92_applied'] else 'not applied'})")
    lines.append(f"  G28    {xyz(o['g28_mm'])}")
    lines.append(f"  G30    {xyz(o['g30_mm'])}")
    return lines


def run(args: argparse.Namespace) -> int:
    fields = request_fields(args)

    def body(client: Client) -> int:
        response = client.call("offsets", **fields)
        print(json.dumps(response, indent=2) if args.json else "\n".join(format_offsets(response["offsets"])))
        return 0
    return with_client(args, body)
