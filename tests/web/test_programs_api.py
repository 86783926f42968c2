"""The program library and the job queue over the web API (real HTTP on loopback, a real
daemon with simulated drives): upload, check result, start by name, queue, refusals as
one-line 4xx JSON, and the OpenAPI document."""

from __future__ import annotations

import asyncio

import aiohttp
import pytest

from tests.helpers import wait_for
from tests.integration.daemon_helpers import daemon_in_process
from tests.web.test_api import get_json, run

SQUARE = b"G21 G90\nG01 X4 Y3 F3000\nG01 X0 Y0\n"


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    with daemon_in_process(tmp_path_factory.mktemp("web-lib") / "data", "", "web-lib") as d:
        yield d


def idle_after(daemon, job_id: str) -> dict:
    wait_for(lambda: (daemon.controller.last_job() or {}).get("id") == job_id, 30.0, f"job {job_id}'s end")
    return daemon.controller.last_job()


def test_upload_check_result_start_by_name_and_delete(daemon):
    async def body(base: str, s: aiohttp.ClientSession) -> None:
        status, added = await get_json(s, "POST", f"{base}/api/v1/programs?name=square.nc", data=SQUARE,
                                       headers={"Content-Type": "text/plain"})
        assert status == 200, added
        assert added["program"]["check"]["blocks"] == 2
        status, listing = await get_json(s, "GET", f"{base}/api/v1/programs")
        assert status == 200 and [p["name"] for p in listing["programs"]] == ["square.nc"]
        status, one = await get_json(s, "GET", f"{base}/api/v1/programs/square.nc")
        assert status == 200 and one["program"]["text"] == SQUARE.decode()
        check = one["program"]["check"]
        assert check["ok"] and check["lines"]["lines_total"] == 3 and check["extent"]["max_mm"] == [4.0, 3.0, 0.0]
        status, job = await get_json(s, "POST", f"{base}/api/v1/jobs", json={"program": "square.nc"})
        assert status == 200 and job["job"]["summary"]["checked_from_store"] is True, job
        last = await asyncio.to_thread(idle_after, daemon, job["job"]["id"])
        assert last["outcome"] == "completed"
        status, _ = await get_json(s, "DELETE", f"{base}/api/v1/programs/square.nc")
        assert status == 200
        status, gone = await get_json(s, "GET", f"{base}/api/v1/programs/square.nc")
        assert status == 404 and gone["error"] == "program 'square.nc': not in the library (nurbsmotion programs list)"
    run(daemon, body)


def test_the_queue_over_the_api(daemon):
    async def body(base: str, s: aiohttp.ClientSession) -> None:
        assert (await get_json(s, "POST", f"{base}/api/v1/programs?name=q.nc", data=SQUARE))[0] == 200
        assert (await get_json(s, "POST", f"{base}/api/v1/queue/pause"))[0] == 200
        status, queued = await get_json(s, "POST", f"{base}/api/v1/jobs", json={"program": "q.nc", "queue": True})
        assert status == 200 and queued["queue"]["entries"][0]["program"] == "q.nc"
        status, second = await get_json(s, "POST", f"{base}/api/v1/queue", json={"program": "q.nc", "start_line": 2})
        assert status == 200 and second["entry"]["id"] == queued["entry"]["id"] + 1
        status, moved = await get_json(s, "PUT", f"{base}/api/v1/queue/{second['entry']['id']}", json={"position": 1})
        assert status == 200 and [e["start_line"] for e in moved["queue"]["entries"]] == [2, None]
        status, _ = await get_json(s, "DELETE", f"{base}/api/v1/queue/{second['entry']['id']}")
        assert status == 200
        status, listing = await get_json(s, "GET", f"{base}/api/v1/queue")
        assert status == 200 and len(listing["queue"]["entries"]) == 1 and listing["queue"]["paused"]
        status, resumed = await get_json(s, "POST", f"{base}/api/v1/queue/resume")
        assert status == 200 and resumed["queue"]["paused"] is None
        await asyncio.to_thread(wait_for, lambda: (daemon.controller.last_job() or {}).get("name") == "q.nc",
                                30.0, "the queue's job to end")
        assert daemon.controller.last_job()["outcome"] == "completed" and not daemon.programs.queue.entries
    run(daemon, body)


def test_bad_library_requests_are_one_line_4xx_and_change_nothing(daemon):
    async def body(base: str, s: aiohttp.ClientSession) -> None:
        cases = [
            ("POST", "/api/v1/programs?name=../x.nc", {"data": SQUARE}, 400, "program name"),
            ("POST", "/api/v1/programs", {"data": SQUARE}, 400, "program name"),
            ("POST", "/api/v1/programs?name=bad.nc", {"data": b"G21\nG01 Q7\n"}, 422, "bad.nc:2"),
            ("POST", "/api/v1/programs?name=bad.nc", {"data": b"\xff\xfe"}, 400, "UTF-8"),
            ("GET", "/api/v1/programs/.hidden.nc", {}, 400, "program name"),
            ("DELETE", "/api/v1/programs/none.nc", {}, 404, "not in the library"),
            ("POST", "/api/v1/jobs", {"json": {"program": "none.nc"}}, 404, "not in the library"),
            ("POST", "/api/v1/jobs", {"json": {"program": "a/b.nc"}}, 400, "library program name"),
            ("POST", "/api/v1/jobs", {"json": {"program": "none.nc", "queue": True}}, 404, "not in the library"),
            ("POST", "/api/v1/jobs", {"json": {"program": "x.nc", "queue": "yes"}}, 400, "queue"),
            ("POST", "/api/v1/jobs", {"json": {"name": "x.nc", "text": "G0 X1\n", "queue": True}}, 400, "queue"),
            ("DELETE", "/api/v1/queue/77", {}, 404, "no queue entry 77"),
            ("DELETE", "/api/v1/queue/x", {}, 400, "whole number"),
            ("PUT", "/api/v1/queue/1", {"json": {}}, 400, "position"),
        ]
        for method, path, kw, code, words in cases:
            status, answer = await get_json(s, method, base + path, **kw)
            assert status == code, (path, answer)
            assert words in answer["error"] + " ".join(answer.get("errors", [])), (path, answer)
            assert "\n" not in answer["error"]
        names = [p["name"] for p in (await get_json(s, "GET", f"{base}/api/v1/programs"))[1]["programs"]]
        assert "bad.nc" not in names
    run(daemon, body)


def test_the_openapi_document_has_the_library_and_the_queue(daemon):
    async def body(base: str, s: aiohttp.ClientSession) -> None:
        _, doc = await get_json(s, "GET", f"{base}/api/v1/openapi.json")
        paths = doc["paths"]
        assert paths["/api/v1/programs"]["post"]["x-daemon-command"] == "programs.add"
        assert "text/plain" in paths["/api/v1/programs"]["post"]["requestBody"]["content"]
        assert "422" in paths["/api/v1/programs"]["post"]["responses"]
        assert paths["/api/v1/programs/{name}"]["delete"]["x-role"] == "operator"
        assert paths["/api/v1/queue/{id}"]["put"]["x-daemon-command"] == "queue.move"
        assert "program" in paths["/api/v1/jobs"]["post"]["requestBody"]["content"]["application/json"]["schema"][
            "properties"]
    run(daemon, body)
