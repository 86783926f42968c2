"""``nurbsmotion daemon --config FILE``: bring the drives up and serve the control socket.

The daemon logs at INFO by default (one structured line per event: ready, job started and
ended, submission rejected, override changed, faults); the simulated drives of
``simulate: true`` log their own state changes only with ``-v``; ``-vv`` is debug.
"""

from __future__ import annotations

import argparse
import logging
import os

from nurbsmotion.cli._control import CONFIG_VARIABLE
from nurbsmotion.config import load_config
from nurbsmotion.errors import InputError
from nurbsmotion.log import setup_logging
from nurbsmotion.service.daemon import run_daemon

HELP = "run the motion service: drives up, control API on a Unix socket, until SIGTERM/SIGINT"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", metavar="FILE", default=os.environ.get(CONFIG_VARIABLE) or None,
                        help=f"machine configuration (YAML; default ${CONFIG_VARIABLE})")


def run(args: argparse.Namespace) -> int:
    if not args.config:
        raise InputError("--config", f"a machine configuration is required (--config FILE or ${CONFIG_VARIABLE})")
    verbosity = getattr(args, "verbose", 0)
    setup_logging(max(1, verbosity))  # an operator reads what the service did
    if verbosity < 1:  # simulated drives are not the service: their state changes are noise here
        logging.getLogger("nurbsmotion.sim").setLevel(logging.WARNING)
    return run_daemon(load_config(args.config))
