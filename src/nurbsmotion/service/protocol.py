"""The control API's wire format: one JSON object per line, each request answered by one line.

Request: ``{"cmd": NAME, ...fields}``; response: ``{"ok": true, ...}`` or
``{"ok": false, "error": "one line naming the field"}`` (program rejections add
``"errors": [one line per problem]``). After ``subscribe`` the connection only pushes
``{"notify": ...}`` lines (service.subscriptions) until the client closes it. Requests longer than :data:`MAX_REQUEST_BYTES` are
refused. ``submit`` and ``programs.add`` carry the program as ``program`` (its text) or, from a
client on this host, as ``program_fd``: the index of a file descriptor sent with the request
line (SCM_RIGHTS, at most :data:`MAX_FDS`; service.program_file), so that the daemon never
holds the text. This module is pure: it turns bytes into checked :class:`Request` records and
records into bytes; the server and the client both use it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

from nurbsmotion.steps import Steps

MAX_REQUEST_BYTES = 80 * 1024 * 1024  # a library program (web.max_upload_mb, default 64 MB) as JSON text
MAX_FDS = 2  # file descriptors a request line may carry (more are closed unread)
PROGRAM_NAME = r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$"  # a library program's name: a file name, no path
DEFAULT_SOCKET = "/tmp/nurbsmotion.sock"  # where the daemon listens unless control.socket says otherwise

# command -> {field: (type name, required)}
COMMANDS: dict[str, dict[str, tuple[str, bool]]] = {
    "submit": {"name": ("string", True), "program": ("string", False), "program_fd": ("number", False),
               "keep_override": ("boolean", False),
               "block_delete": ("boolean", False), "optional_stop": ("boolean", False),
               "start_line": ("number", False)},  # start from this line of the program (program.gcode_start)
    # the program library (service.programs): checked once when added, started by name
    "programs.add": {"name": ("string", True), "program": ("string", False), "program_fd": ("number", False)},
    "programs.list": {},
    "programs.get": {"name": ("string", True)},
    "programs.remove": {"name": ("string", True)},
    "start": {"name": ("string", True), "keep_override": ("boolean", False), "block_delete": ("boolean", False),
              "optional_stop": ("boolean", False), "start_line": ("number", False)},
    # the persistent job queue of library programs (service.job_queue)
    "queue.list": {},
    "queue.add": {"name": ("string", True), "start_line": ("number", False)},
    "queue.remove": {"id": ("number", True)},
    "queue.move": {"id": ("number", True), "position": ("number", True)},
    "queue.clear": {},
    "queue.pause": {},
    "queue.resume": {},
    "mdi": {"text": ("string", True)},
    "status": {},
    "job": {"id": ("string", True)},
    "jobs": {"limit": ("number", False)},
    "stop": {},
    "abort": {},
    "hold": {},
    "resume": {},
    "reset": {},
    "override": {"percent": ("number", True)},
    "offsets": {"system": ("string", False), "x": ("number", False), "y": ("number", False), "z": ("number", False),
                "clear": ("string", False), "select": ("string", False)},
    "inject_fault": {"spec": ("string", True)},  # only when the daemon simulates its drives
    "home": {"axes": ("string", False)},  # names separated by spaces or commas; none: every axis with homing:
    "jog": {"axis": ("string", True), "distance": ("number", False), "position": ("number", False),
            "direction": ("string", False), "speed": ("number", False)},
    "jog_renew": {},
    "jog_stop": {},
    # the connection then carries pushed status changes and events (service.subscriptions)
    "subscribe": {"max_hz": ("number", False)},
}


class ProtocolError(Exception):
    """A request that cannot be served; ``str()`` is the one-line error for the response."""


@dataclass(frozen=True)
class Request:
    cmd: str
    fields: dict[str, Any] = field(default_factory=dict)
    files: tuple[int, ...] = ()  # descriptors sent with the line (``program_fd``); the server closes them after


def _type_ok(value: Any, type_name: str) -> bool:
    if type_name == "string":
        return isinstance(value, str)
    if type_name == "boolean":
        return isinstance(value, bool)
    return isinstance(value, (int, float)) and not isinstance(value, bool) and abs(value) <= 1e308  # no NaN/inf/huge int


def parse_request(line: bytes) -> Request:
    """Decode and check one request line; ProtocolError names the offending field."""
    if len(line) > MAX_REQUEST_BYTES:
        raise ProtocolError(f"request: longer than the {MAX_REQUEST_BYTES // (1024 * 1024)} MB limit")
    try:
        obj = json.loads(line.decode("utf-8"))
    except UnicodeDecodeError as err:
        raise ProtocolError(f"request: not UTF-8 ({err.reason} at byte {err.start})") from None
    except json.JSONDecodeError as err:
        raise ProtocolError(f"request: malformed JSON ({err.msg} at column {err.colno})") from None
    except (RecursionError, ValueError) as err:  # nested too deeply; an integer of over 4300 digits
        raise ProtocolError(f"request: malformed JSON ({str(err).split(':')[0]})") from None
    if not isinstance(obj, dict):
        raise ProtocolError(f"request: must be a JSON object, got {type(obj).__name__}")
    cmd = obj.get("cmd")
    if not isinstance(cmd, str):
        raise ProtocolError(f"field 'cmd': must be a string naming the command, got {cmd!r}"[:200])
    spec = COMMANDS.get(cmd)
    if spec is None:
        raise ProtocolError(f"field 'cmd': unknown command {cmd[:40]!r}; expected one of {', '.join(COMMANDS)}")
    fields: dict[str, Any] = {}
    for key, value in obj.items():
        if key == "cmd":
            continue
        if key not in spec:
            raise ProtocolError(f"field {key[:40]!r}: unknown for command {cmd!r}"
                                f"{'; expected ' + ', '.join(spec) if spec else ' (it takes no fields)'}")
        type_name, _ = spec[key]
        if not _type_ok(value, type_name):
            raise ProtocolError(f"field {key!r}: must be a {type_name}, got {type(value).__name__}")
        fields[key] = value
    for key, (_, required) in spec.items():
        if required and key not in fields:
            raise ProtocolError(f"field {key!r}: required for command {cmd!r}")
    if "program_fd" in spec and ("program" in fields) == ("program_fd" in fields):
        raise ProtocolError(f"field 'program': required for command {cmd!r} (its text, or 'program_fd' with the file sent "
                            "along), not both")
    return Request(cmd, fields)


def encode(obj: dict[str, Any]) -> bytes:
    """One response or request line (compact JSON + newline; NaN/inf become null). The C
    encoder refuses a non-finite float: only then is the object walked (_finite) in Python,
    which took the status publisher ~75 % of an encode (issue 22)."""
    return (_dumps(obj) + "\n").encode("utf-8")


def encode_steps(obj: dict[str, Any]) -> Steps[bytes]:
    """:func:`encode`'s line, one top-level field a step (steps.Steps): each json.dumps is one
    C call that holds the interpreter lock throughout, so the daemon encodes a status answer
    in the cycle thread's slack (fieldbus.cycle_slack), where it cannot delay a wake-up."""
    if not all(isinstance(key, str) for key in obj):
        return encode(obj)  # JSON's own key conversions: in one go
    parts = []
    for key, value in obj.items():
        yield None
        parts.append(f"{json.dumps(key)}:{_dumps(value)}")
    return ("{" + ",".join(parts) + "}\n").encode("utf-8")


def _dumps(value: Any) -> str:
    try:
        return json.dumps(value, separators=(",", ":"), allow_nan=False)
    except ValueError:
        return json.dumps(_finite(value), separators=(",", ":"))


class EncodedResponse(dict[str, Any]):
    """A response whose line was encoded ahead (``line``: :func:`encode_steps`' bytes); the
    control server sends ``line`` instead of encoding the response again."""

    line: bytes = b""


def error_response(message: str, errors: list[str] | None = None) -> dict[str, Any]:
    response: dict[str, Any] = {"ok": False, "error": message.replace("\n", " ")}
    if errors:
        response["errors"] = errors
    return response


def _finite(obj: Any) -> Any:
    """Replace non-finite floats by None (JSON has no NaN)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


# ---------------------------------------------------------------- pushed status changes
# The ``changes`` of a ``{"notify": "status"}`` line (service.subscriptions): the daemon makes them,
# a client (the web gateway's fan-out) applies them to the full status it was sent first.
Status = dict[str, Any]


def status_changes(old: Status | None, new: Status) -> Status:
    """The fields of ``new`` that differ from ``old``: nested dicts by key, anything else whole.
    A key that disappeared is reported as None."""
    if old is None:
        return dict(new)
    changes: Status = {}
    for key, value in new.items():
        before = old.get(key, _MISSING)
        if before is value or before == value:  # compared in C: most fields have not changed
            continue
        if isinstance(value, dict) and isinstance(before, dict):
            inner = status_changes(before, value)
            if inner:
                changes[key] = inner
        else:
            changes[key] = value
    for key in old.keys() - new.keys():
        changes[key] = None
    return changes


def merge_changes(older: Status, newer: Status) -> Status:
    """Two successive change sets as one (newer wins; nested dicts merged by key); likewise a
    full status and the changes after it give the full status now. ``older`` is not changed."""
    merged = dict(older)
    for key, value in newer.items():
        before = merged.get(key)
        merged[key] = merge_changes(before, value) if isinstance(value, dict) and isinstance(before, dict) else value
    return merged


_MISSING = object()
