"""Shared by the control commands (run, status, stop, abort, reset, override, jobs):
finding the socket, connecting, and the exit codes of a control client.

The socket, first found wins: ``--socket PATH``, ``--config FILE`` (its control.socket),
``$NURBSMOTION_SOCKET``, ``$NURBSMOTION_CONFIG``, the default ``control.socket`` (the one
the shipped configurations use).

Exit codes: 0 done, 1 the job ended without completing (fault, stop, abort), 2 the request
was refused (bad program, bad value, busy, nothing to stop), 3 no daemon answers.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any, Callable

from nurbsmotion.service.client import Client, DaemonUnavailable, RequestFailed
from nurbsmotion.service.protocol import DEFAULT_SOCKET

EXIT_NO_DAEMON = 3
EXIT_REFUSED = 2
SOCKET_VARIABLE = "NURBSMOTION_SOCKET"
CONFIG_VARIABLE = "NURBSMOTION_CONFIG"


def add_socket_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--config", metavar="FILE", help=f"machine configuration (its control.socket is used; "
                                                       f"default ${CONFIG_VARIABLE})")
    group.add_argument("--socket", metavar="PATH", help=f"control socket (default ${SOCKET_VARIABLE}, "
                                                       f"else {DEFAULT_SOCKET})")


def config_path(args: argparse.Namespace) -> str | None:
    """``--config``, else ``$NURBSMOTION_CONFIG`` (None: neither)."""
    return getattr(args, "config", None) or os.environ.get(CONFIG_VARIABLE) or None


def socket_path(args: argparse.Namespace) -> str:
    """The control socket (module docstring: the first of the five places that gives one)."""
    if getattr(args, "socket", None):
        return str(args.socket)
    if getattr(args, "config", None):
        return _configured_socket(args.config)
    if os.environ.get(SOCKET_VARIABLE):
        return os.environ[SOCKET_VARIABLE]
    config = config_path(args)
    if config:
        return _configured_socket(config)
    return DEFAULT_SOCKET


def _configured_socket(path: str) -> str:
    """control.socket of the machine configuration ``path`` (the whole file is checked)."""
    from nurbsmotion.config import load_config  # yaml, canopen and the EDS: only when a config is named

    return load_config(path).control.socket


def error_line(args: argparse.Namespace, message: str) -> None:
    sys.stderr.write(f"nurbsmotion {args.command}: error: {message}\n")


def with_client(args: argparse.Namespace, body: Callable[[Client], int], quiet_no_daemon: bool = False) -> int:
    """Run ``body`` with a connected client; the client errors become exit codes 2 and 3
    (``quiet_no_daemon``: exit 3 without the error line, the caller has another way)."""
    try:
        with Client(socket_path(args)) as client:
            return body(client)
    except DaemonUnavailable as err:
        if not quiet_no_daemon:
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
