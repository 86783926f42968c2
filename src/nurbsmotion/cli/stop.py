"""``nurbsmotion stop``: controlled stop of the running job, along the path."""

from __future__ import annotations

import argparse

from nurbsmotion.cli._control import add_socket_arguments, simple_command, with_client

HELP = "controlled stop of the running job (decelerates along the path, drives stay enabled)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_socket_arguments(parser)


def run(args: argparse.Namespace) -> int:
    return with_client(args, simple_command("stop", lambda r: f"job {r['job']}: stopping along the path" if r['job'] else "homing: stopping the search"))
