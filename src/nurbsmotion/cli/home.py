"""``nurbsmotion home [AXIS...]``: home the axes (every axis with ``homing:`` when none is
named) in the configured order, follow the homing, print each axis' result."""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from nurbsmotion.cli._control import add_socket_arguments, error_line, with_client
from nurbsmotion.service.client import Client

HELP = "home the axes (all with a homing: section, or those named) in the configured order"
POLL_S = 0.2


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("axes", nargs="*", metavar="AXIS", help="axes to home (default: every axis with homing:)")
    add_socket_arguments(parser)


def follow_homing(client: Client, names: list[str]) -> dict[str, Any]:
    """Poll until the homing thread ended; print each axis as it becomes homed; the last status."""
    shown: set[str] = set()
    while True:
        homing = client.call("status")["homing"]
        for name in names:
            if name not in shown and homing["axes"].get(name) == "homed":
                shown.add(name)
                print(f"axis {name}: homed")
        if not homing["busy"]:
            return homing
        time.sleep(POLL_S)


def run(args: argparse.Namespace) -> int:
    def body(client: Client) -> int:
        names = client.call("home", axes=" ".join(args.axes))["axes"]
        print(f"homing {', '.join(names)}")
        try:
            homing = follow_homing(client, names)
        except KeyboardInterrupt:
            sys.stderr.write("the homing goes on in the daemon (nurbsmotion status shows it)\n")
            return 1
        if homing["error"]:
            error_line(args, homing["error"])
            return 1
        return 0
    return with_client(args, body)
