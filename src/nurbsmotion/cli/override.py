"""``nurbsmotion override PERCENT``: feed override 0-150 % (playback rate of the set-points)."""

from __future__ import annotations

import argparse

from nurbsmotion.cli._control import add_socket_arguments, simple_command, with_client
from nurbsmotion.cli._format import figure

HELP = "feed override in percent (0-150; above 100 clamped to what keeps the axis limits)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("percent", type=float, help="0 pauses along the path, 100 runs as planned")
    add_socket_arguments(parser)


def run(args: argparse.Namespace) -> int:
    return with_client(args, simple_command(
        "override", lambda r: f"override: requested {figure(r['requested_percent'], 'g')} %, "
                              f"effective {figure(r['effective_percent'], 'g')} %", percent=args.percent))
