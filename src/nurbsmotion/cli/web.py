"""``nurbsmotion web``: the web gateway (API, WebSocket, console page) beside the daemon, and
``nurbsmotion web keys add NAME --role operator|observer | list | remove NAME`` for its keys.

The gateway reads the machine's YAML for ``web:`` (listen address, auth, upload limit, CORS,
niceness, CPUs), ``control.socket`` and ``data_dir`` (where the keys are); the options override it.
It is a separate process: it talks to the daemon only through the control socket (docs/web.md).
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace
from typing import TYPE_CHECKING

from nurbsmotion.cli._control import config_path
from nurbsmotion.config import ControlConfig, MachineConfig, WebConfig, load_config, parse_listen
from nurbsmotion.errors import InputError
from nurbsmotion.runtime import thread_cpus

if TYPE_CHECKING:
    from nurbsmotion.web.app import WebSettings

HELP = "serve the machine's web console and HTTP/WebSocket API beside the daemon (docs/web.md)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", metavar="FILE", help="machine configuration: its web:, control.socket and "
                                                         "data_dir (default $NURBSMOTION_CONFIG)")
    parser.add_argument("--socket", metavar="PATH", help="the daemon's control socket")
    parser.add_argument("--data-dir", metavar="DIR", help="where the API keys are kept (DATA_DIR/web/keys.json)")
    parser.add_argument("--listen", metavar="HOST:PORT", help=f"default {WebConfig.host}:{WebConfig.port}; any "
                                                               f"address but loopback requires API keys")
    parser.add_argument("--require-auth", action="store_true", help="require API keys on loopback too")
    sub = parser.add_subparsers(dest="web_command", metavar="ACTION", parser_class=type(parser))
    keys = sub.add_parser("keys", help="the gateway's API keys").add_subparsers(
        dest="keys_command", metavar="ACTION", required=True, parser_class=type(parser))
    add = keys.add_parser("add", help="make a key (printed once) for NAME with a role")
    add.add_argument("name")
    add.add_argument("--role", required=True, choices=("operator", "observer"))
    keys.add_parser("list", help="the keys' names and roles")
    remove = keys.add_parser("remove", help="remove NAME's key")
    remove.add_argument("name")


def _machine(args: argparse.Namespace) -> MachineConfig | None:
    path = config_path(args)
    return load_config(path) if path else None


def settings_of(args: argparse.Namespace) -> "WebSettings":
    """The gateway's WebSettings from the YAML and the options (options win)."""
    from nurbsmotion.web.app import WebSettings

    machine = _machine(args)
    web = machine.web if machine is not None else WebConfig()
    if args.listen:
        try:
            host, port = parse_listen(args.listen)
        except ValueError as err:
            raise InputError("--listen", str(err)) from None
        web = replace(web, host=host, port=port)
    from nurbsmotion.web.priority import cpus_for

    cpus_for(web.cpus, thread_cpus(), os.cpu_count() or 1)  # a CPU this machine lacks: one error, before anything starts
    socket = args.socket or (machine.control.socket if machine is not None else ControlConfig().socket)
    data_dir = args.data_dir or (machine.data_dir if machine is not None else "var/nurbsmotion")
    return WebSettings(socket=socket, data_dir=data_dir, host=web.host, port=web.port,
                       require_auth=web.require_auth or args.require_auth,
                       max_upload_bytes=int(web.max_upload_mb * 1024 * 1024), cors_origins=web.cors_origins,
                       nice=web.nice, cpus=web.cpus)


def _keys(args: argparse.Namespace) -> int:
    from nurbsmotion.web.auth import KeyStore, Role

    machine = _machine(args)
    store = KeyStore(args.data_dir or (machine.data_dir if machine is not None else "var/nurbsmotion"))
    if args.keys_command == "add":
        key = store.add(args.name, Role(args.role))
        print(f"key for {args.name} ({args.role}), shown once: {key}")
    elif args.keys_command == "remove":
        store.remove(args.name)
        print(f"removed the key of {args.name}")
    else:
        for record in store.keys():
            print(f"{record.name}\t{record.role.value}")
    return 0


def run(args: argparse.Namespace) -> int:
    if args.web_command == "keys":
        return _keys(args)
    try:
        import aiohttp  # noqa: F401 - the gateway's one dependency beyond the daemon's
    except ImportError:
        raise InputError("web", "needs aiohttp: pip install 'nurbsmotion[web]'") from None
    from nurbsmotion.web.app import run_gateway

    settings = settings_of(args)
    print(f"nurbsmotion web: serving http://{settings.host}:{settings.port}/ for the daemon at {settings.socket}",
          file=sys.stderr)
    run_gateway(settings)
    return 0
