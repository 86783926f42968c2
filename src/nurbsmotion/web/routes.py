"""The JSON HTTP API under ``/api/v1/``: each route is one daemon request (service.protocol).

The table ``ROUTES`` is the API: the app registers it, the OpenAPI document is made from it,
and the auth middleware reads each route's role from it. A route turns the HTTP request
(path, query, JSON body) into the daemon request's fields; the daemon's own checks answer
the rest, so the CLI and the web give the same errors:

- the daemon's ``ok: true`` -> 200 with its answer;
- a refused request (``ok: false``) -> 409 ``{"error": ...}``; a rejected program (submit,
  mdi: every line it names in ``errors``) -> 422 with ``errors``;
- a request the gateway cannot read (not JSON, a wrong type) -> 400; no daemon -> 503.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Awaitable, Callable

from aiohttp import web

from nurbsmotion.web.auth import Role
from nurbsmotion.web.daemon_link import DaemonLink, DaemonUnreachable

API = "/api/v1"
PROGRAM_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")
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


async def submit_fields(request: web.Request) -> Fields:
    """A program to run: the raw G-code body with ``?name=`` (and ``&start_line=N``), or JSON
    ``{"name", "text", "start_line"?}``."""
    if request.content_type == "application/json":
        body = pick(await json_body(request), "name", "text", "keep_override", "block_delete", "optional_stop",
                    "start_line")
        name, text = body.pop("name", None), body.pop("text", None)
        if not isinstance(text, str):
            raise BadRequest("body 'text': the program's G-code is required as a string")
    else:
        name, body = request.query.get("name"), {}
        start_line = request.query.get("start_line")
        if start_line is not None:
            if not start_line.isdigit():
                raise BadRequest(f"query 'start_line': must be a line number, got {start_line!r}")
            body["start_line"] = int(start_line)
        raw = await request.read()
        try:
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError as err:
            raise BadRequest(f"body: not a UTF-8 text file (byte {err.start})") from None
    if not isinstance(name, str) or not PROGRAM_NAME.match(name):
        raise BadRequest(f"program name {name!r}: 1-128 letters, digits, '.', '_' or '-' (no path), e.g. part.nc")
    return {"name": name, "program": text, **body}


ROUTES: tuple[Route, ...] = (
    Route("GET", f"{API}/status", "status", Role.OBSERVER, "the machine's status (as `nurbsmotion status --json`)"),
    Route("GET", f"{API}/jobs", "jobs", Role.OBSERVER, "the newest job records, newest first", jobs_query,
          query=("limit",)),
    Route("POST", f"{API}/jobs", "submit", Role.OPERATOR,
          "run a program: raw G-code body with ?name=part.nc (&start_line=N), or JSON {name, text, start_line?}; "
          "checked completely before anything moves; from line N the tool approaches safely (docs/programs.md)",
          submit_fields,
          body={"type": "object", "required": ["name", "text"],
                "properties": {"name": {"type": "string"}, "text": {"type": "string"},
                               "keep_override": {"type": "boolean"}, "block_delete": {"type": "boolean"},
                               "optional_stop": {"type": "boolean"},
                               "start_line": {"type": "integer", "minimum": 1}}}, query=("name", "start_line")),
    Route("GET", f"{API}/jobs/{{id}}", "job", Role.OBSERVER, "one job's record", job_id),
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


PROGRAM_COMMANDS = ("submit", "mdi")  # their refusals name program lines: 422


def answer(cmd: str, response: dict[str, Any]) -> web.Response:
    """The daemon's answer as HTTP (module docstring)."""
    if response.get("ok"):
        return web.json_response(response)
    if cmd in PROGRAM_COMMANDS and response.get("errors"):
        return web.json_response({"error": response.get("error", "rejected"), "errors": response["errors"]},
                                 status=422)
    return web.json_response({"error": response.get("error", "refused")}, status=409)


def error(status: int, message: str) -> web.Response:
    return web.json_response({"error": message}, status=status)


def route_handler(route: Route, link: DaemonLink) -> Callable[[web.Request], Awaitable[web.Response]]:
    async def handle(request: web.Request) -> web.Response:
        try:
            fields = await route.fields_of(request) if route.fields_of is not None else {}
            return answer(route.cmd, await link.request(route.cmd, **fields))
        except BadRequest as err:
            return error(400, str(err))
        except DaemonUnreachable as err:
            return error(503, str(err))
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
