"""``python -m nurbsmotion`` and the ``nurbsmotion`` command (pyproject's entry point).

Ctrl-C while the CLI is imported (seconds on a loaded host) ends as quietly as Ctrl-C later
(exit code 130, cli._endings): the handler below is installed when this module is imported,
before anything else of the CLI, because a signal that arrives before ``main``'s first
statement is raised there, outside any ``try``. Nothing has started while it is in force, so
it ends the process at once; the CLI's own handling takes over before it runs a command.
Only the interpreter's start and pip's two-line script come before it.
"""

import os
import signal
import sys

EXIT_INTERRUPTED = 130  # 128 + SIGINT, as cli._endings (not imported: it would import the CLI)


def _interrupted_while_starting(signum: int, frame: object) -> None:
    os.write(2, b"nurbsmotion: interrupted\n")
    os._exit(EXIT_INTERRUPTED)


if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # not when started with SIGINT ignored
    signal.signal(signal.SIGINT, _interrupted_while_starting)


def main() -> int:
    from nurbsmotion.cli import main as cli_main

    try:
        if signal.getsignal(signal.SIGINT) is _interrupted_while_starting:
            signal.signal(signal.SIGINT, signal.default_int_handler)
        return cli_main()
    except KeyboardInterrupt:  # after the line above, before cli.main's own try
        sys.stderr.write("nurbsmotion: interrupted\n")
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    raise SystemExit(main())
