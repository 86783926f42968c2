"""``nurbsmotion daemon --config FILE``: bring the drives up and serve the control socket."""

from __future__ import annotations

import argparse

from nurbsmotion.config import load_config
from nurbsmotion.service.daemon import run_daemon

HELP = "run the motion service: drives up, control API on a Unix socket, until SIGTERM/SIGINT"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", metavar="FILE", required=True, help="machine configuration (YAML)")


def run(args: argparse.Namespace) -> int:
    return run_daemon(load_config(args.config))
