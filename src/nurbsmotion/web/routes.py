"""The JSON HTTP API under ``/api/v1/``: each route is one daemon request (service.protocol).

The table ``ROUTES`` is the API: the app registers it, the OpenAPI document is made from it,
and the auth middleware reads each route's role from it. A route turns the HTTP request
(path, query, JSON body) into the daemon request's fields; the daemon's own checks answer
the rest, so the CLI and the web give the same errors:

- the daemon's ``ok: true`` -> 200 with its answer;
- a refused request (``ok: false``) -> 409 ``{"error": ...}``; a rejected program (submit,
  start, mdi, a library upload: every line it names in ``errors``) -> 422 with ``errors``; a
  library program or queue entry that is not there -> 404;
- a request the gateway cannot read (not JSON, a wrong type) -> 400; no daemon -> 503.

A raw program body (``POST programs``, ``POST jobs?name=``) is streamed into an unnamed file
and sent along as the file (``program_fd``: web.upload), as the CLI sends its file.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Awaitable, BinaryIO, Callable

from aiohttp import web

from nurbsmotion.errors import InputError
from nurbsmotion.service.protocol import PROGRAM_NAME as PROGRAM_NAME_PATTERN
from nurbsmotion.web.auth import Role
from nurbsmotion.web.daemon_link import DaemonLink, DaemonUnreachable
from nurbsmotion.web.upload import upload_file

API = "/api/v1"
PROGRAM_NAME = re.compile(PROGRAM_NAME_PATTERN)
COMMAND = "__cmd__"  # a fields_of may name another daemon command than its route's (POST jobs: start, queue.add)
FILE = "__file__"  # an upload's open file (raw_program), sent along with the request and closed after
JOB_FILE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")
FILE_TYPES = {".png": "image/png", ".csv": "text/csv", ".json": "application/json", ".log": "text/plain",
              ".asc": "text/plain", ".yaml": "text/yaml"}

Fields = dict[str, Any]
FieldsOf = Callable[[web.Request], Awaitable[Fields]]


class BadRequest(Exception):
    """The HTTP request itself is unreadable: 400 with this one line."""


@dataclass(frozen=True)
class Route:
    """One API route: HTTP method and path, the daemon command it sends, the fields it takes."""

    method: str
    path: str
    cmd: str
    role: Role
    summary: str
    fields_of: FieldsOf | None = None
    body: dict[str, Any] = field(default_factory=dict)  # JSON schema of the body (OpenAPI)
    query: tuple[str, ...] = ()


async def json_body(request: web.Request) -> dict[str, Any]:
    """The request's JSON object (an empty body is ``{}``)."""
    if not request.can_read_body:
        return {}
    try:
        body = await request.json(loads=json.loads)
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise BadRequest(f"body: not JSON ({err})") from None
    if not isinstance(body, dict):
        raise BadRequest(f"body: must be a JSON object, got {type(body).__name__}")
    return body


def pick(body: dict[str, Any], *names: str) -> Fields:
    """The named fields of ``body`` (the daemon checks their types); an unknown one is refused."""
    unknown = set(body) - set(names)
    if unknown:
        raise BadRequest(f"body: unknown field {sorted(unknown)[0]!r}; expected {', '.join(names) or 'none'}")
    return {k: v for k, v in body.items() if k in names}


def body_fields(*names: str) -> FieldsOf:
    async def fields_of(request: web.Request) -> Fields:
        return pick(await json_body(request), *names)
    return fields_of


async def no_fields(request: web.Request) -> Fields:
    pick(await json_body(request))
    return {}


async def jobs_query(request: web.Request) -> Fields:
    limit = request.query.get("limit")
    if limit is None:
        return {}
    try:
        return {"limit": int(limit)}
    except ValueError:
        raise BadRequest(f"query 'limit': must be a whole number, got {limit!r}") from None


async def job_id(request: web.Request) -> Fields:
    return {"id": request.match_info["id"]}


async def home_fields(request: web.Request) -> Fields:
    body = pick(await json_body(request), "axes")
    axes = body.get("axes", [])
    if isinstance(axes, str):
        axes = axes.replace(",", " ").split()
    if not isinstance(axes, list) or not all(isinstance(a, str) for a in axes):
        raise BadRequest("body 'axes': must be a list of axis names, e.g. [\"X\", \"Y\"]")
    return {"axes": " ".join(axes)} if axes else {}


def checked_name(name: Any, what: str = "program name") -> str:
    if not isinstance(name, str) or not PROGRAM_NAME.match(name):
        raise BadRequest(f"{what} {name!r}: 1-128 letters, digits, '.', '_' or '-' (no path), e.g. part.nc")
    return name


async def raw_program(request: web.Request) -> Fields:
    """The fields of an upload: ``?name=`` and the raw body as an unnamed file (web.upload),
    sent to the daemon as the CLI sends a file (``program_fd``: route_handler)."""
    name = checked_name(request.query.get("name"))
    try:
        upload = await upload_file(request, name)
    except InputError as err:  # not UTF-8: the CLI's line for the same file
        raise BadRequest(str(err)) from None
    return {"name": name, "program_fd": 0, FILE: upload}


async def submit_fields(request: web.Request) -> Fields:
    """A program to run: the raw G-code body with ``?name=`` (and ``&start_line=N``), JSON
    ``{"name", "text", "start_line"?}``, or a library program: JSON ``{"program": NAME,
    "start_line"?}`` (``"queue": true``: queued instead, service.job_queue)."""
    if request.content_type != "application/json":
        return await raw_submit_fields(request)
    body = pick(await json_body(request), "name", "text", "program", "queue", "keep_override", "block_delete",
                "optional_stop", "start_line")
    if "program" in body:
        return library_start(body)
    name, text = body.pop("name", None), body.pop("text", None)
    if not isinstance(text, str):
        raise BadRequest("body 'text': the program's G-code is required as a string "
                         "(or 'program': the name of a library program)")
    if "queue" in body:
        raise BadRequest("body 'queue': only library programs are queued ({\"program\": NAME, \"queue\": true})")
    return {"name": checked_name(name), "program": text, **body}


async def raw_submit_fields(request: web.Request) -> Fields:
    """``POST jobs?name=part.nc(&start_line=N)`` with the raw G-code body (raw_program)."""
    start_line = request.query.get("start_line")
    if start_line is not None and not start_line.isdigit():
        raise BadRequest(f"query 'start_line': must be a line number, got {start_line!r}")
    return {**await raw_program(request), **({} if start_line is None else {"start_line": int(start_line)})}


def library_start(body: Fields) -> Fields:
    """``{"program": NAME, ...}``: start it (``start``) or queue it (``"queue": true``)."""
    name = checked_name(body.pop("program"), "body 'program': library program name")
    queue = body.pop("queue", False)
    if not isinstance(queue, bool):
        raise BadRequest(f"body 'queue': must be true or false, got {queue!r}")
    if queue:
        return {COMMAND: "queue.add", "name": name, **pick(body, "start_line")}
    return {COMMAND: "start", "name": name, **body}


async def program_name(request: web.Request) -> Fields:
    return {"name": checked_name(request.match_info["name"])}


async def queue_add_fields(request: web.Request) -> Fields:
    """``{"program": NAME, "start_line"?}``: queue a library program."""
    return library_start({**pick(await json_body(request), "program", "start_line"), "queue": True})


def entry_id(request: web.Request) -> int:
    text = request.match_info["id"]
    if not text.isdigit():
        raise BadRequest(f"queue entry {text!r}: a whole number (GET {API}/queue lists them)")
    return int(text)


async def queue_entry(request: web.Request) -> Fields:
    pick(await json_body(request))
    return {"id": entry_id(request)}


async def queue_move_fields(request: web.Request) -> Fields:
    body = pick(await json_body(request), "position")
    if "position" not in body:
        raise BadRequest("body 'position': required, 1 = the next to run")
    return {"id": entry_id(request), "position": body["position"]}


RAW = {"type": "string"}  # a route whose body is the raw program text (OpenAPI: text/plain)
PROGRAM_BODY = {"type": "object", "required": ["program"],
                "properties": {"program": {"type": "string", "description": "a library program's name"},
                               "start_line": {"type": "integer", "minimum": 1}}}


ROUTES: tuple[Route, ...] = (
    Route("GET", f"{API}/status", "status", Role.OBSERVER, "the machine's status (as `nurbsmotion status --json`)"),
    Route("GET", f"{API}/jobs", "jobs", Role.OBSERVER, "the newest job records, newest first", jobs_query,
          query=("limit",)),
    Route("POST", f"{API}/jobs", "submit", Role.OPERATOR,
          "run a program: raw G-code body with ?name=part.nc (&start_line=N), or JSON {name, text, start_line?}, "
          "or a library program: JSON {program, start_line?} (daemon command start; with \"queue\": true "
          "queued: queue.add); checked completely before anything moves (a library program: checked when added); "
          "from line N the tool approaches safely (docs/programs.md)",
          submit_fields,
          body={"type": "object", "oneOf": [{"required": ["name", "text"]}, {"required": ["program"]}],
                "properties": {"name": {"type": "string"}, "text": {"type": "string"},
                               "program": {"type": "string", "description": "a library program's name"},
                               "queue": {"type": "boolean", "description": "queue the library program"},
                               "keep_override": {"type": "boolean"}, "block_delete": {"type": "boolean"},
                               "optional_stop": {"type": "boolean"},
                               "start_line": {"type": "integer", "minimum": 1}}}, query=("name", "start_line")),
    Route("GET", f"{API}/jobs/{{id}}", "job", Role.OBSERVER, "one job's record", job_id),
    Route("GET", f"{API}/programs", "programs.list", Role.OBSERVER,
          "the program library: each program's size, when added and its check (blocks, lines, extent)", no_fields),
    Route("POST", f"{API}/programs", "programs.add", Role.OPERATOR,
          "add a program to the library: raw G-code body with ?name=part.nc; read and checked against the machine "
          "once (file:line errors: 422, not added), then started by name without a second check",
          raw_program, body=RAW, query=("name",)),
    Route("GET", f"{API}/programs/{{name}}", "programs.get", Role.OBSERVER,
          "one library program: its text and its check (blocks, lines, extent, errors)", program_name),
    Route("DELETE", f"{API}/programs/{{name}}", "programs.remove", Role.OPERATOR, "remove a library program",
          program_name),
    Route("GET", f"{API}/queue", "queue.list", Role.OBSERVER,
          "the job queue: its entries in order and whether it is paused (why)", no_fields),
    Route("POST", f"{API}/queue", "queue.add", Role.OPERATOR,
          "queue a library program (also POST jobs with {\"program\": NAME, \"queue\": true})",
          queue_add_fields, body=PROGRAM_BODY),
    Route("DELETE", f"{API}/queue", "queue.clear", Role.OPERATOR, "remove every queue entry", no_fields),
    Route("DELETE", f"{API}/queue/{{id}}", "queue.remove", Role.OPERATOR, "remove one queue entry", queue_entry),
    Route("PUT", f"{API}/queue/{{id}}", "queue.move", Role.OPERATOR, "move a queue entry to a position (1 = next)",
          queue_move_fields, body={"type": "object", "required": ["position"],
                                   "properties": {"position": {"type": "integer", "minimum": 1}}}),
    Route("POST", f"{API}/queue/pause", "queue.pause", Role.OPERATOR, "start no more queue entries", no_fields),
    Route("POST", f"{API}/queue/resume", "queue.resume", Role.OPERATOR,
          "start the queue's entries again when the machine is idle (after a fault, abort or restart)", no_fields),
    Route("POST", f"{API}/machine/hold", "hold", Role.OPERATOR, "hold the job at rest on its path", no_fields),
    Route("POST", f"{API}/machine/resume", "resume", Role.OPERATOR, "continue a held or paused job", no_fields),
    Route("POST", f"{API}/machine/stop", "stop", Role.OPERATOR, "controlled stop along the path", no_fields),
    Route("POST", f"{API}/machine/abort", "abort", Role.OBSERVER, "quick stop (any authenticated client)", no_fields),
    Route("POST", f"{API}/machine/reset", "reset", Role.OPERATOR, "acknowledge faults", no_fields),
    Route("POST", f"{API}/machine/home", "home", Role.OPERATOR, "home the axes (all with homing: when none given)",
          home_fields, body={"type": "object", "properties": {"axes": {"type": "array", "items": {"type": "string"}}}}),
    Route("POST", f"{API}/machine/jog", "jog", Role.OPERATOR,
          "jog one axis: distance (incremental), position (absolute) or direction '+'/'-' (continuous while "
          "renewed: POST machine/jog/renew every 0.2 s, or the WebSocket's jog_renew)",
          body_fields("axis", "distance", "position", "direction", "speed"),
          body={"type": "object", "required": ["axis"],
                "properties": {"axis": {"type": "string"}, "distance": {"type": "number"},
                               "position": {"type": "number"}, "direction": {"type": "string", "enum": ["+", "-"]},
                               "speed": {"type": "number"}}}),
    Route("POST", f"{API}/machine/jog/renew", "jog_renew", Role.OPERATOR, "keep a continuous jog moving", no_fields),
    Route("POST", f"{API}/machine/jog/stop", "jog_stop", Role.OPERATOR, "stop a jog", no_fields),
    Route("POST", f"{API}/machine/mdi", "mdi", Role.OPERATOR, "run G-code lines from where the axes are",
          body_fields("text"), body={"type": "object", "required": ["text"], "properties": {"text": {"type": "string"}}}),
    Route("PUT", f"{API}/machine/override", "override", Role.OPERATOR, "feed override in percent (0-150)",
          body_fields("percent"),
          body={"type": "object", "required": ["percent"], "properties": {"percent": {"type": "number"}}}),
    Route("GET", f"{API}/offsets", "offsets", Role.OBSERVER, "the work offsets", no_fields),
    Route("PUT", f"{API}/offsets", "offsets", Role.OPERATOR, "set (system + x/y/z), clear or select work offsets",
          body_fields("system", "x", "y", "z", "clear", "select"),
          body={"type": "object", "properties": {k: {"type": "string"} if k in ("system", "clear", "select")
                                                 else {"type": "number"}
                                                 for k in ("system", "x", "y", "z", "clear", "select")}}),
)


PROGRAM_COMMANDS = ("submit", "start", "mdi", "programs.add")  # their refusals name program lines: 422
NOT_THERE = ("programs.get", "programs.remove")  # a well-formed name the daemon refuses: no such program


def answer(cmd: str, response: dict[str, Any]) -> web.Response:
    """The daemon's answer as HTTP (module docstring)."""
    if response.get("ok"):
        return web.json_response(response)
    error_text = response.get("error", "refused")
    if cmd in PROGRAM_COMMANDS and response.get("errors") and not error_text.startswith("program '"):
        return web.json_response({"error": response.get("error", "rejected"), "errors": response["errors"]},
                                 status=422)
    if cmd in NOT_THERE or error_text.startswith("program '") and "not in the library" in error_text or \
            error_text.startswith("field 'id': no queue entry"):
        return web.json_response({"error": error_text}, status=404)
    return web.json_response({"error": error_text}, status=409)


def error(status: int, message: str) -> web.Response:
    return web.json_response({"error": message}, status=status)


def route_handler(route: Route, link: DaemonLink) -> Callable[[web.Request], Awaitable[web.Response]]:
    async def handle(request: web.Request) -> web.Response:
        try:
            fields = await route.fields_of(request) if route.fields_of is not None else {}
        except BadRequest as err:
            return error(400, str(err))
        cmd = fields.pop(COMMAND, route.cmd)
        upload: BinaryIO | None = fields.pop(FILE, None)
        try:
            return answer(cmd, await link.request(cmd, files=() if upload is None else (upload.fileno(),), **fields))
        except DaemonUnreachable as err:
            return error(503, str(err))
        finally:
            if upload is not None:
                upload.close()
    return handle


def job_file_handler(link: DaemonLink) -> Callable[[web.Request], Awaitable[web.StreamResponse]]:
    """``GET jobs/{id}/files/{name}``: a file of the job's record (plot.png, trace.csv, ...)."""
    async def handle(request: web.Request) -> web.StreamResponse:
        name = request.match_info["name"]
        if not JOB_FILE.match(name):
            return error(400, f"file {name!r}: a plain file name of the job's record, e.g. plot.png")
        try:
            info = await link.request("job", id=request.match_info["id"])
        except DaemonUnreachable as err:
            return error(503, str(err))
        if not info.get("ok"):
            return error(404, info.get("error", "no such job"))
        job = info["job"]
        folder = Path(job["folder"])
        if name not in job.get("files", []) or not folder.is_absolute():
            return error(404, f"job {job['id']} has no file {name!r}; it has {', '.join(job.get('files', []))}")
        path = (folder / name).resolve()
        if path.parent != folder.resolve() or not path.is_file():
            return error(404, f"job {job['id']} has no file {name!r}")
        return web.FileResponse(path, headers={"Content-Type": FILE_TYPES.get(path.suffix, "application/octet-stream")})
    return handle
