"""The ``nurbsmotion`` command.

Each sub-command is one module in this package (a plug-in, like python-can's interfaces):
it defines ``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``; the
command name is the module name with ``_`` -> ``-``. Modules whose name starts with ``_``
are helpers, not commands. Only the CLI and the service put the layers together.

Exit codes: 0 success, 1 the job failed (fault, stop), 2 bad input (one line per error on
stderr), 3 no daemon answers on the control socket (run, status, stop, abort, hold, resume, reset,
override, offsets), 70 internal error, 130 interrupted (Ctrl-C), 141 the reader of the output
left (``| head``; cli._endings).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import pkgutil
import sys
from types import ModuleType

from nurbsmotion import __version__
from nurbsmotion.cli._endings import interrupted, output_closed, reader_gone
from nurbsmotion.errors import InputError, NurbsmotionError
from nurbsmotion.log import setup_logging
from nurbsmotion.runtime import keep_freed_memory

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERNAL = 70

log = logging.getLogger(__name__)


class _Parser(argparse.ArgumentParser):
    """argparse that reports bad arguments as one line and exit code 2 (no usage dump)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(EXIT_BAD_INPUT)


def command_modules() -> dict[str, ModuleType]:
    """Discover the sub-command modules of this package, by command name."""
    found: dict[str, ModuleType] = {}
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(module, "run") and hasattr(module, "add_arguments"):
            found[info.name.replace("_", "-")] = module
    return found


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="nurbsmotion", description="NURBS motion controller: plan feed, interpolate, stream set-points to CiA-402 drives.")
    parser.add_argument("--version", action="version", version=f"nurbsmotion {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, module in command_modules().items():
        p = sub.add_parser(name, help=getattr(module, "HELP", ""), description=getattr(module, "HELP", ""))
        p.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command; Ctrl-C and a reader that closed stdout end it quietly at any moment,
    its imports included (exit codes 130 and 141: cli._endings)."""
    args: argparse.Namespace | None = None
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        code = _run_command(parser, args)
        sys.stdout.flush()  # a reader that left shows here, not in the interpreter's last flush
        return code
    except KeyboardInterrupt:
        return interrupted(getattr(args, "command", None))
    except BrokenPipeError as err:
        if reader_gone(sys.stdout) or reader_gone(sys.stderr):
            return output_closed()
        return _internal_error(getattr(args, "command", None), err)


def _run_command(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    setup_logging(getattr(args, "verbose", 0))
    keep_freed_memory()  # no page faults for every large numpy temporary (runtime.py)
    if not getattr(args, "_run", None):
        parser.print_help(sys.stderr)
        return EXIT_BAD_INPUT
    try:
        return int(args._run(args) or 0)
    except InputError as err:
        for line in str(err).splitlines():
            sys.stderr.write(f"nurbsmotion {args.command}: error: {line}\n")
        return EXIT_BAD_INPUT
    except NurbsmotionError as err:
        sys.stderr.write(f"nurbsmotion {args.command}: error: {err}\n")
        return EXIT_FAILED
    except BrokenPipeError:
        raise  # main() tells a closed output from an internal error
    except Exception as err:  # noqa: BLE001 - last line of defence: one line, no traceback
        return _internal_error(args.command, err)


def _internal_error(command: str | None, err: BaseException) -> int:
    log.debug("internal error", exc_info=err)
    sys.stderr.write(f"nurbsmotion {command}: internal error: {type(err).__name__}: {err} (run with -vv for details)\n")
    return EXIT_INTERNAL
