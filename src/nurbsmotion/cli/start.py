"""``nurbsmotion start NAME``: start a program of the daemon's library (``programs add``) and
follow it as ``run`` does: the same options, output and exit codes (0 completed, 1 stopped,
aborted or fault, 2 refused, 3 no daemon). The daemon checked it when it was added: it is not
read and checked again unless the file, the configuration or where it starts changed."""

from __future__ import annotations

import argparse

from nurbsmotion.cli._control import add_socket_arguments, with_client
from nurbsmotion.cli.run import add_job_options, job_fields, start_and_follow
from nurbsmotion.service.client import Client

HELP = "start a program of the daemon's library by name, follow it and print the outcome (as run does)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", help="the program's name in the library (nurbsmotion programs list)")
    add_job_options(parser)
    add_socket_arguments(parser)


def run(args: argparse.Namespace) -> int:
    def body(client: Client) -> int:
        return start_and_follow(client, args, args.name, "start", {"name": args.name, **job_fields(args)})

    return with_client(args, body)
