"""The OpenAPI 3.1 document of the API, made from the route table (routes.ROUTES)."""

from __future__ import annotations

import re
from typing import Any, Iterable

from nurbsmotion import __version__
from nurbsmotion.web.routes import API, NOT_THERE, PROGRAM_COMMANDS, RAW, Route

ERROR = {"type": "object", "required": ["error"], "properties": {"error": {"type": "string"},
                                                                  "errors": {"type": "array", "items": {"type": "string"}}}}


def _error(description: str) -> dict[str, Any]:
    return {"description": description, "content": {"application/json": {"schema": {"$ref": "#/components/schemas/Error"}}}}


def operation(route: Route) -> dict[str, Any]:
    op: dict[str, Any] = {
        "summary": route.summary,
        "operationId": f"{route.method.lower()}_{re.sub(r'[^a-z0-9]+', '_', route.path[len(API):].lower()).strip('_')}",
        "x-daemon-command": route.cmd,
        "x-role": route.role.value,
        "responses": {"200": {"description": f"the daemon's answer to {route.cmd!r}",
                              "content": {"application/json": {"schema": {"type": "object"}}}},
                      "400": _error("the request cannot be read"), "401": _error("authentication required"),
                      "403": _error("the key's role does not allow it"), "409": _error("refused by the daemon"),
                      "503": _error("no daemon")},
    }
    params = [{"name": name, "in": "path", "required": True, "schema": {"type": "string"}}
              for name in re.findall(r"{(\w+)}", route.path)]
    params += [{"name": name, "in": "query", "required": False, "schema": {"type": "string"}} for name in route.query]
    if params:
        op["parameters"] = params
    raw = {"text/plain": {"schema": {"type": "string", "description": "the G-code, with ?name="}}}
    if route.body:
        content: dict[str, Any] = {"application/json": {"schema": route.body}}
        if route.cmd == "submit":
            content.update(raw)
        op["requestBody"] = {"required": route.method != "GET", "content": raw if route.body == RAW else content}
    if route.cmd in PROGRAM_COMMANDS:
        op["responses"]["422"] = _error("the program was rejected: one line per problem in errors")
    if route.cmd in NOT_THERE or route.cmd in ("start", "submit", "queue.add", "queue.remove", "queue.move"):
        op["responses"]["404"] = _error("no such library program or queue entry")
    return op


def openapi_document(routes: Iterable[Route]) -> dict[str, Any]:
    paths: dict[str, dict[str, Any]] = {}
    for route in routes:
        paths.setdefault(route.path, {})[route.method.lower()] = operation(route)
    paths[f"{API}/jobs/{{id}}/files/{{name}}"] = {"get": {
        "summary": "a file of the job's record (plot.png, trace.csv, outcome.json, ...)", "x-role": "observer",
        "parameters": [{"name": n, "in": "path", "required": True, "schema": {"type": "string"}} for n in ("id", "name")],
        "responses": {"200": {"description": "the file"}, "404": _error("no such job or file")}}}
    paths[f"{API}/access/oneshot"] = {"post": {
        "summary": "a token valid once for 5 s (for a WebSocket's ?token=)", "x-role": "observer",
        "responses": {"200": {"description": "the token", "content": {"application/json": {"schema": {
            "type": "object", "properties": {"token": {"type": "string"}, "valid_s": {"type": "number"}}}}}}}}}
    paths[f"{API}/ws"] = {"get": {
        "summary": "WebSocket: the daemon's status changes and events (docs/daemon.md, subscribe); send "
                   "{\"id\": n, \"cmd\": NAME, ...} for requests", "x-role": "observer",
        "responses": {"101": {"description": "switching protocols"}}}}
    return {
        "openapi": "3.1.0",
        "info": {"title": "nurbsmotion machine API", "version": __version__,
                 "description": "The daemon's control requests over HTTP (docs/web.md)."},
        "servers": [{"url": "/"}],
        "components": {"schemas": {"Error": ERROR},
                       "securitySchemes": {"bearer": {"type": "http", "scheme": "bearer"},
                                           "apiKey": {"type": "apiKey", "in": "header", "name": "X-Api-Key"}}},
        "security": [{"bearer": []}, {"apiKey": []}, {}],
        "paths": paths,
    }
