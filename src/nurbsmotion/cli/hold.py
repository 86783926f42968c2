"""``nurbsmotion hold``: bring the running job to rest on its path and keep it (``resume`` continues)."""

from __future__ import annotations

import argparse

from nurbsmotion.cli._control import add_socket_arguments, simple_command, with_client

HELP = "hold the running job: decelerate to rest along the path, keep the job (resume continues it)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_socket_arguments(parser)


def run(args: argparse.Namespace) -> int:
    return with_client(args, simple_command("hold", lambda r: f"job {r['job']}: holding (coming to rest on the path)"))
