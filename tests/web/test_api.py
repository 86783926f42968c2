"""The web gateway against a real daemon (simulated drives) over real HTTP on loopback:
every route, the daemon's refusals as 4xx JSON, keys and roles, one-shot tokens, the
WebSocket's relay and requests, and a dropped WebSocket that stops a continuous jog."""

from __future__ import annotations

import asyncio
import contextlib
import json
from pathlib import Path
from typing import Any, Awaitable, Callable

import aiohttp
import pytest

from nurbsmotion.web.app import WebSettings, make_app
from tests.web.ports import free_port
from tests.web.serving import serving
from nurbsmotion.web.auth import KeyStore, Role
from tests.integration.daemon_helpers import daemon_in_process
from tests.helpers import wait_for

PROGRAM = "G21 G90\nG01 X4 Y3 F3000\nG01 X0 Y0\n"
LONG = "G21 G90\nG01 X60 F600\n"



def gateway(settings: WebSettings) -> contextlib.AbstractAsyncContextManager[str]:
    return serving(make_app(settings), settings.host, settings.port)


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    with daemon_in_process(tmp_path_factory.mktemp("web") / "data", "", "web") as d:
        yield d


def run(daemon, body: Callable[[str, aiohttp.ClientSession], Awaitable[Any]], **settings: Any) -> Any:
    """``body(base_url, session)`` against a gateway for ``daemon`` on a free loopback port."""
    web_settings = WebSettings(socket=str(daemon.config.control.socket), data_dir=str(daemon.config.data_dir),
                               port=free_port(), **settings)

    async def main() -> Any:
        async with gateway(web_settings) as base, aiohttp.ClientSession() as session:
            return await body(base, session)
    return asyncio.run(main())


async def get_json(session: aiohttp.ClientSession, method: str, url: str, **kw: Any) -> tuple[int, Any]:
    async with session.request(method, url, **kw) as response:
        return response.status, await response.json()


def back_at_origin(daemon) -> None:
    wait_for(lambda: daemon.controller.status()["job"] is None, 30.0, "the job to end")


def test_status_jobs_and_a_program_run_through_the_api(daemon):
    async def body(base: str, s: aiohttp.ClientSession) -> None:
        status, answer = await get_json(s, "GET", f"{base}/api/v1/status")
        assert status == 200 and answer["state"] == "idle" and len(answer["axes"]) == 3
        status, job = await get_json(s, "POST", f"{base}/api/v1/jobs?name=square.nc", data=PROGRAM.encode(),
                                     headers={"Content-Type": "text/plain"})
        assert status == 200, job
        job_id = job["job"]["id"]
        await asyncio.to_thread(back_at_origin, daemon)
        status, record = await get_json(s, "GET", f"{base}/api/v1/jobs/{job_id}")
        assert status == 200 and record["job"]["outcome"]["outcome"] == "completed"
        status, listing = await get_json(s, "GET", f"{base}/api/v1/jobs?limit=1")
        assert status == 200 and listing["jobs"][0]["id"] == job_id
        async with s.get(f"{base}/api/v1/jobs/{job_id}/files/outcome.json") as response:
            assert response.status == 200 and json.loads(await response.text())["outcome"] == "completed"
    run(daemon, body)


def test_bad_requests_get_one_line_json_errors_and_change_nothing(daemon):
    async def body(base: str, s: aiohttp.ClientSession) -> None:
        before = (await get_json(s, "GET", f"{base}/api/v1/jobs"))[1]["total"]
        cases = [
            ("POST", "/api/v1/jobs?name=../etc/passwd", {"data": b"G0 X1\n"}, 400, "program name"),
            ("POST", "/api/v1/jobs?name=bad.nc", {"data": b"\xff\xfe\x00G0"}, 400, "UTF-8"),
            ("POST", "/api/v1/jobs?name=bad.nc", {"data": b"G01 Q7\n"}, 422, "bad.nc:1"),
            ("POST", "/api/v1/jobs?name=far.nc", {"data": b"G21 G90\nG01 X500 F600\n"}, 422, "soft limit"),
            ("PUT", "/api/v1/machine/override", {"json": {"percent": "fast"}}, 409, "percent"),
            ("PUT", "/api/v1/machine/override", {"json": {"percent": 80, "extra": 1}}, 400, "extra"),
            ("POST", "/api/v1/machine/stop", {}, 409, "no job"),
            ("POST", "/api/v1/machine/mdi", {"data": b"not json", "headers": {"Content-Type": "application/json"}},
             400, "not JSON"),
            ("GET", "/api/v1/jobs/nope", {}, 409, "nope"),
            ("GET", "/api/v1/jobs?limit=many", {}, 400, "limit"),
            ("POST", "/api/v1/jobs?name=a.nc&start_line=x", {"data": b"G0 X1\n"}, 400, "start_line"),
            ("POST", "/api/v1/jobs?name=a.nc&start_line=9", {"data": b"G21 G90\nG01 X1 F600\n"}, 422, "a.nc:9"),
            ("GET", "/api/v1/nothing", {}, 404, "/api/v1/nothing"),
            ("DELETE", "/api/v1/status", {}, 405, "status"),
        ]
        for method, path, kw, code, words in cases:
            status, answer = await get_json(s, method, base + path, **kw)
            assert status == code, (path, answer)
            assert set(answer) <= {"error", "errors"} and words in json.dumps(answer), (path, answer)
            assert "\n" not in answer["error"]
        after = (await get_json(s, "GET", f"{base}/api/v1/jobs"))[1]["total"]
        assert after - before == 3  # the three rejected programs leave their records, as with the CLI; nothing ran
        assert (await get_json(s, "GET", f"{base}/api/v1/status"))[1]["state"] == "idle"
    run(daemon, body)


def test_an_upload_over_the_limit_is_refused_with_413(daemon):
    async def body(base: str, s: aiohttp.ClientSession) -> None:
        status, answer = await get_json(s, "POST", f"{base}/api/v1/jobs?name=big.nc", data=b"G0 X0\n" * 400)
        assert status == 413 and "MB limit" in answer["error"]
    run(daemon, body, max_upload_bytes=1024)


def test_keys_and_roles_observers_read_operators_move_everyone_may_abort(daemon, tmp_path):
    store = KeyStore(daemon.config.data_dir)
    observer, operator = store.add(f"obs{tmp_path.name[-6:]}", Role.OBSERVER), store.add(f"op{tmp_path.name[-6:]}",
                                                                                       Role.OPERATOR)
    mode = (Path(daemon.config.data_dir) / "web" / "keys.json").stat().st_mode & 0o777
    assert mode == 0o600
    assert observer not in (Path(daemon.config.data_dir) / "web" / "keys.json").read_text()

    async def body(base: str, s: aiohttp.ClientSession) -> None:
        assert (await get_json(s, "GET", f"{base}/api/v1/status"))[0] == 401
        assert (await get_json(s, "GET", f"{base}/api/v1/status", headers={"X-Api-Key": "wrong"}))[0] == 401
        obs = {"Authorization": f"Bearer {observer}"}
        assert (await get_json(s, "GET", f"{base}/api/v1/status", headers=obs))[0] == 200
        status, answer = await get_json(s, "PUT", f"{base}/api/v1/machine/override", json={"percent": 90}, headers=obs)
        assert status == 403 and "operator" in answer["error"]
        assert (await get_json(s, "POST", f"{base}/api/v1/machine/abort", headers=obs))[0] in (200, 409)
        op = {"X-Api-Key": operator}
        assert (await get_json(s, "PUT", f"{base}/api/v1/machine/override", json={"percent": 100}, headers=op))[0] == 200
        status, token = await get_json(s, "POST", f"{base}/api/v1/access/oneshot", headers=obs)
        assert status == 200
        async with s.ws_connect(f"{base}/api/v1/ws?token={token['token']}") as ws:
            assert (await ws.receive_json())["role"] == "observer"
        async with s.ws_connect(f"{base}/api/v1/ws?token={token['token']}") as ws:  # used once only
            assert "invalid" in (await ws.receive_json())["error"]
        async with s.ws_connect(f"{base}/api/v1/ws") as ws:  # the key as the first message
            await ws.send_json({"auth": operator})
            assert (await ws.receive_json())["role"] == "operator"
        for _ in range(12):  # failed attempts are limited per address
            await get_json(s, "GET", f"{base}/api/v1/status", headers={"X-Api-Key": "guess"})
        status, answer = await get_json(s, "GET", f"{base}/api/v1/status", headers=op)
        assert status == 429 and "failed attempts" in answer["error"]
    run(daemon, body, require_auth=True)


def test_the_websocket_relays_status_and_events_and_serves_requests(daemon):
    async def body(base: str, s: aiohttp.ClientSession) -> None:
        async with s.ws_connect(f"{base}/api/v1/ws") as ws:
            assert (await ws.receive_json())["notify"] == "welcome"
            first = await ws.receive_json()
            assert first["subscribed"] and first["status"]["state"] == "idle"
            await ws.send_json({"id": 1, "cmd": "mdi", "text": "G21 G90 G01 X1 F600"})
            seen: list[dict] = []
            while not any(m.get("event") == "job_ended" for m in seen):
                seen.append(await asyncio.wait_for(ws.receive_json(), 30.0))
            [reply] = [m for m in seen if m.get("id") == 1]
            assert reply["response"]["ok"]
            assert any(m.get("event") == "job_started" for m in seen)
            await ws.send_json({"id": 2, "cmd": "inject_fault", "spec": "x"})
            while True:
                m = await ws.receive_json()
                if m.get("id") == 2:
                    assert "cmd" in m["error"]
                    break
            await ws.send_json({"id": 3, "cmd": "mdi", "text": "G21 G90 G01 X0 F600"})
        await asyncio.to_thread(back_at_origin, daemon)
    run(daemon, body)


def test_a_dropped_websocket_during_a_continuous_jog_stops_the_axis(daemon):
    async def body(base: str, s: aiohttp.ClientSession) -> None:
        ws = await s.ws_connect(f"{base}/api/v1/ws")
        await ws.receive_json()
        await ws.send_json({"id": 1, "cmd": "jog", "axis": "X", "direction": "+", "speed": 5})
        for _ in range(3):  # renew as the page does while the button is held
            await asyncio.sleep(0.2)
            await ws.send_json({"id": 2, "cmd": "jog_renew"})
        await ws.close()  # the tablet's Wi-Fi drops: no more renewals
        await asyncio.to_thread(wait_for, lambda: daemon.controller.status()["job"] is None, 10.0,
                                "the jog stopped by its lease")
        status = await asyncio.to_thread(daemon.controller.status)
        x = status["axes"][0]["commanded_mm"]
        assert 0 < x < 10  # it moved, then stopped within the lease, far from the +100 mm soft limit
        assert status["last_job"]["outcome"] == "stopped"
        await asyncio.to_thread(daemon.controller.mdi, "G21 G90 G53 G01 X0 F600")
        await asyncio.to_thread(back_at_origin, daemon)
    run(daemon, body)


def test_the_openapi_document_lists_every_route_with_its_role(daemon):
    async def body(base: str, s: aiohttp.ClientSession) -> None:
        status, doc = await get_json(s, "GET", f"{base}/api/v1/openapi.json")
        assert status == 200 and doc["openapi"].startswith("3.")
        assert doc["paths"]["/api/v1/machine/abort"]["post"]["x-role"] == "observer"
        assert doc["paths"]["/api/v1/jobs"]["post"]["x-daemon-command"] == "submit"
        async with s.get(f"{base}/") as page:
            assert page.status == 200 and 'data-testid="machine-state"' in await page.text()
    run(daemon, body)
