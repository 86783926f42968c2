"""Shared by the control commands (run, status, stop, abort, reset, override): finding the
socket, connecting, and the exit codes of a control client.

Exit codes: 0 done, 1 the job ended without completing (fault, stop, abort), 2 the request
was refused (bad program, bad value, busy, nothing to stop), 3 no daemon answers.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any, Callable

from nurbsmotion.config import ControlConfig, load_config
from nurbsmotion.service.client import Client, DaemonUnavailable, RequestFailed

EXIT_NO_DAEMON = 3
EXIT_REFUSED = 2


def add_socket_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--config", metavar="FILE", help="machine configuration (its control.socket is used)")
    group.add_argument("--socket", metavar="PATH", help=f"control socket (default {ControlConfig().socket})")


def socket_path(args: argparse.Namespace) -> str:
    if getattr(args, "socket", None):
        return str(args.socket)
    if getattr(args, "config", None):
        return load_config(args.config).control.socket
    return ControlConfig().socket


def error_line(args: argparse.Namespace, message: str) -> None:
    sys.stderr.write(f"nurbsmotion {args.command}: error: {message}\n")


def with_client(args: argparse.Namespace, body: Callable[[Client], int]) -> int:
    """Run ``body`` with a connected client; the client errors become exit codes 2 and 3."""
    try:
        with Client(socket_path(args)) as client:
            return body(client)
    except DaemonUnavailable as err:
        error_line(args, str(err))
        return EXIT_NO_DAEMON
    except RequestFailed as err:
        for line in err.errors:
            error_line(args, line)
        return EXIT_REFUSED


def simple_command(cmd: str, describe: Callable[[dict[str, Any]], str], **fields: Any) -> Callable[[Client], int]:
    """Body for a one-request command that prints one line describing the response."""
    def body(client: Client) -> int:
        print(describe(client.call(cmd, **fields)))
        return 0
    return body
