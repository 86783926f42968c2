"""``nurbsmotion resume``: continue a held job, or one paused by M0/M1/M6, from where it rests."""

from __future__ import annotations

import argparse

from nurbsmotion.cli._control import add_socket_arguments, simple_command, with_client

HELP = "continue a held job (hold, M0, M1, M6 tool change) from where it rests"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_socket_arguments(parser)


def run(args: argparse.Namespace) -> int:
    return with_client(args, simple_command("resume", lambda r: f"job {r['job']}: resumed"))
