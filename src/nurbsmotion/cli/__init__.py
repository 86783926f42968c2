"""The ``nurbsmotion`` command.

Each sub-command is one module in this package (a plug-in, like python-can's interfaces):
it defines ``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``; the
command name is the module name with ``_`` -> ``-``. Modules whose name starts with ``_``
are helpers, not commands. Only the CLI and the service put the layers together.

COMMANDS lists every command with its module and HELP, so that ``--help`` and a command
import nothing but the one command's module: ``status`` must not wait for numpy, the
planner or canopen (tests/cli/test_main.py checks that the table and the modules agree).

Exit codes: 0 success, 1 the job failed (fault, stop), 2 bad input (one line per error on
stderr), 3 no daemon answers on the control socket (run, status, stop, abort, hold, resume, reset,
override, offsets), 70 internal error, 130 interrupted (Ctrl-C), 141 the reader of the output
left (``| head``; cli._endings).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from dataclasses import dataclass
from types import ModuleType

from nurbsmotion import __version__
from nurbsmotion.cli._endings import interrupted, output_closed, reader_gone
from nurbsmotion.errors import InputError, NurbsmotionError
from nurbsmotion.log import setup_logging

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


@dataclass(frozen=True)
class Command:
    module: str  # below nurbsmotion.cli
    help: str  # the module's HELP
    computes: bool = False  # plans or simulates in this process: numpy temporaries (keep_freed_memory)


COMMANDS: dict[str, Command] = {
    "abort": Command("abort", "quick stop of the running job (drives stop on their quick-stop ramp and disable; then reset)"),
    "check": Command("check", "validate a G-code or YAML curve program and summarise it", computes=True),
    "compare": Command("compare", "run every interpolation algorithm on a program and compare the measured figures", computes=True),
    "daemon": Command("daemon", "run the motion service: drives up, control API on a Unix socket, until SIGTERM/SIGINT", computes=True),
    "demo": Command("demo", "run Wang's Table 1 curve on simulated drives (daemon + drives in this process) and report", computes=True),
    "drives": Command("drives", "find and identify the drives on a bus (scan), check them against the configuration (check, --live)"),
    "hold": Command("hold", "hold the running job: decelerate to rest along the path, keep the job (resume continues it)"),
    "home": Command("home", "home the axes (all with a homing: section, or those named) in the configured order"),
    "jobs": Command("jobs", "list the job records (newest first) or show one: outcome, line reached, times, faults, overrides"),
    "jog": Command("jog", "jog one axis: X+10 (by 10 mm), X 25 (to 25 mm), X+ / X- (continuous until Ctrl-C), or stop"),
    "mdi": Command("mdi", "run G-code lines (MDI) from where the axes are; each argument is one line"),
    "offsets": Command("offsets", "show or set the work offsets G54-G59.3, G92 and G28/G30 positions (between jobs)"),
    "override": Command("override", "feed override in percent (0-150; above 100 clamped to what keeps the axis limits)"),
    "programs": Command("programs", "the daemon's program library: add FILE (checked once), list, show NAME, remove NAME"),
    "plan": Command("plan", "interpolate a program cycle by cycle and report the measured chord error, acceleration, jerk", computes=True),
    "queue": Command("queue", "the daemon's job queue of library programs: add NAME, list, remove ID, move ID POS, clear, pause, resume"),
    "reset": Command("reset", "acknowledge faults and re-enable the drives (no job may be running)"),
    "resume": Command("resume", "continue a held job (hold, M0, M1, M6 tool change) from where it rests"),
    "run": Command("run", "submit a program (G-code or YAML) to the daemon, follow it and print the outcome"),
    "sim": Command("sim", "run simulated CiA-402 drives for the configuration's axes (and its io node) until SIGINT/SIGTERM", computes=True),
    "start": Command("start", "start a program of the daemon's library by name, follow it and print the outcome (as run does)"),
    "status": Command("status", "show the daemon's state, job progress, positions, following errors and faults"),
    "stop": Command("stop", "controlled stop of the running job (decelerates along the path, drives stay enabled)"),
    "web": Command("web", "serve the machine's web console and HTTP/WebSocket API beside the daemon (docs/web.md)"),
}


def command_modules() -> dict[str, ModuleType]:
    """Discover (import) every sub-command module of this package, by command name: what
    COMMANDS must list."""
    import pkgutil

    found: dict[str, ModuleType] = {}
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(module, "run") and hasattr(module, "add_arguments"):
            found[info.name.replace("_", "-")] = module
    return found


def chosen_command(argv: list[str]) -> str | None:
    """The COMMAND word of ``argv``: the first word after the top-level -v/-vv/--verbose, if
    it is not an option."""
    for word in argv:
        if word == "--verbose" or (len(word) > 1 and word[0] == "-" and set(word[1:]) == {"v"}):
            continue
        return None if word.startswith("-") else word
    return None


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser for ``argv``: every command listed (name and help from COMMANDS), the
    arguments only of the command ``argv`` names (only its module is imported)."""
    parser = _Parser(prog="nurbsmotion", description="NURBS motion controller: plan feed, interpolate, stream set-points to CiA-402 drives.")
    parser.add_argument("--version", action="version", version=f"nurbsmotion {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    chosen = chosen_command(sys.argv[1:] if argv is None else argv)
    for name, command in COMMANDS.items():
        p = sub.add_parser(name, help=command.help, description=command.help)
        if name != chosen:
            continue
        p.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
        module = importlib.import_module(f"{__name__}.{command.module}")
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command; Ctrl-C and a reader that closed stdout end it quietly at any moment,
    its imports included (exit codes 130 and 141: cli._endings)."""
    args: argparse.Namespace | None = None
    try:
        parser = build_parser(argv)
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
    if args.command in COMMANDS and COMMANDS[args.command].computes:
        from nurbsmotion.runtime import keep_freed_memory  # ctypes: not for the control clients

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
