"""``nurbsmotion abort``: quick stop of the running job."""

from __future__ import annotations

import argparse

from nurbsmotion.cli._control import add_socket_arguments, simple_command, with_client

HELP = "quick stop of the running job (drives stop on their quick-stop ramp and disable; then reset)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_socket_arguments(parser)


def run(args: argparse.Namespace) -> int:
    return with_client(args, simple_command("abort", lambda r: f"job {r['job']}: quick stop" if r['job'] else "homing: quick stop of every axis"))
