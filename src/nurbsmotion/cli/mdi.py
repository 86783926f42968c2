"""``nurbsmotion mdi "G01 X10 Y5 F600"``: run G-code lines from where the axes are, as a job
named ``<mdi>`` (same checks and record as a program), show progress, print the outcome."""

from __future__ import annotations

import argparse
from nurbsmotion.cli._control import add_socket_arguments, with_client
from nurbsmotion.cli.run import start_and_follow

MDI_NAME = "<mdi>"  # service.job_common.MDI_NAME (not imported: the client stays light)
HELP = "run G-code lines (MDI) from where the axes are; each argument is one line"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("lines", nargs="+", metavar="LINE", help='G-code, e.g. "G01 X10 Y5 F600"')
    parser.add_argument("--no-progress", action="store_true", help="only print the outcome")
    add_socket_arguments(parser)


def run(args: argparse.Namespace) -> int:
    text = "\n".join(args.lines) + "\n"
    return with_client(args, lambda client: start_and_follow(client, args, MDI_NAME, "mdi", {"text": text}))
