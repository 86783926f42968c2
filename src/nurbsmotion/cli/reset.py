"""``nurbsmotion reset``: acknowledge faults and re-enable the drives."""

from __future__ import annotations

import argparse

from nurbsmotion.cli._control import add_socket_arguments, simple_command, with_client

HELP = "acknowledge faults and re-enable the drives (no job may be running)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_socket_arguments(parser)


def run(args: argparse.Namespace) -> int:
    return with_client(args, simple_command("reset", lambda r: f"faults reset; state {r['state']}"))
