"""``nurbsmotion jog X+10`` (incremental), ``jog X 25.0`` (absolute, machine mm),
``jog X+ --speed 20`` (continuous until Ctrl-C or ``jog stop``), ``jog stop``.

A continuous jog renews its lease with the daemon at every status poll (~0.2 s); when the
client dies the daemon stops the axis after 0.5 s (service.jog)."""

from __future__ import annotations

import argparse
import re
from typing import Any

from nurbsmotion.cli._control import EXIT_REFUSED, add_socket_arguments, error_line, simple_command, with_client
from nurbsmotion.cli.run import _display, follow_and_report
from nurbsmotion.service.client import Client, RequestFailed

HELP = "jog one axis: X+10 (by 10 mm), X 25 (to 25 mm), X+ / X- (continuous until Ctrl-C), or stop"
JOG_WORD = re.compile(r"^([A-Za-z])([+-])?([0-9]*\.?[0-9]*)$")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("jog", metavar="AXIS[+-][DIST]", help="X+10, X-2.5, X+ (continuous), X (then POSITION), or stop")
    parser.add_argument("position", nargs="?", type=float, metavar="POSITION",
                        help="absolute target in machine mm (with a bare axis: jog X 25.0)")
    parser.add_argument("--speed", type=float, metavar="MM_S", help="speed in mm/s (default 10)")
    parser.add_argument("--no-progress", action="store_true", help="only print the outcome")
    add_socket_arguments(parser)


def jog_fields(word: str, position: float | None, speed: float | None) -> dict[str, Any]:
    """The ``jog`` request of the command line (ValueError: one line saying what is wrong)."""
    match = JOG_WORD.match(word)
    if match is None:
        raise ValueError(f"{word!r}: expected AXIS+DIST, AXIS-DIST, AXIS+, AXIS- or AXIS POSITION (e.g. X+10)")
    axis, sign, number = match.groups()
    fields: dict[str, Any] = {"axis": axis.upper()}
    if sign is None:
        if number or position is None:
            raise ValueError(f"{word!r}: an absolute jog is AXIS POSITION (e.g. X 25.0)")
        fields["position"] = position
    elif position is not None:
        raise ValueError(f"{word!r} takes no POSITION (got {position:g})")
    elif number:
        fields["distance"] = float(number) * (1 if sign == "+" else -1)
    else:
        fields["direction"] = sign
    if speed is not None:
        fields["speed"] = speed
    return fields


class _Renewing:
    """The progress display of a continuous jog that also renews its lease at each poll."""

    def __init__(self, client: Client, inner: Any) -> None:
        self.client, self.inner = client, inner

    def update(self, status: dict[str, Any]) -> None:
        try:
            self.client.call("jog_renew")
        except RequestFailed:
            pass  # the jog ended meanwhile: follow sees it next
        if self.inner is not None:
            self.inner.update(status)

    def close(self) -> None:
        if self.inner is not None:
            self.inner.close()


def run(args: argparse.Namespace) -> int:
    if args.jog.lower() == "stop":
        return with_client(args, simple_command("jog_stop", lambda r: f"job {r['job']}: jog stopping"))
    try:
        fields = jog_fields(args.jog, args.position, args.speed)
    except ValueError as err:
        error_line(args, str(err))
        return EXIT_REFUSED

    def body(client: Client) -> int:
        response = client.request("jog", **fields)
        if not response.get("ok"):
            for line in response.get("errors") or [response.get("error", "refused")]:
                error_line(args, line)
            return EXIT_REFUSED
        job = response["job"]
        inner = _display(f"jog {args.jog}", args.no_progress)
        display = _Renewing(client, inner) if response["jog"]["continuous"] else inner
        info = follow_and_report(client, args, job, display, "jog")
        if info is None:
            return 1
        outcome = (info.get("outcome") or {}).get("outcome")
        return 0 if outcome == "completed" or (response["jog"]["continuous"] and outcome == "stopped") else 1
    return with_client(args, body)
