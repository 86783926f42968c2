"""A raw program upload reaches the daemon as a file, never as text (web.upload; real HTTP on
loopback, a real daemon with simulated drives in this process): the same library entry as
``nurbsmotion programs add`` of the same file, a 10^6-line upload that the process holds no
copy of, and the bad uploads refused with the CLI's own lines, leaving nothing behind."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from typing import Any, AsyncIterator

import aiohttp
import pytest

from nurbsmotion.cli import main
from nurbsmotion.web.upload import MEMFD_NAME
from tests.integration.daemon_helpers import daemon_in_process
from tests.web.test_api import get_json, run
from tests.web.test_programs_api import idle_after

BOM = b"\xef\xbb\xbf"


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    with daemon_in_process(tmp_path_factory.mktemp("web-upload") / "data", "", "web-upload") as d:
        yield d


def zigzag_lines(count: int) -> list[str]:
    """``count`` short moves inside the soft limits, after the modal header."""
    return ["G21 G90 F3000\n"] + [f"G01 X{(i % 50) * 0.1:.1f} Y{(i % 7) * 0.2:.1f}\n" for i in range(1, count + 1)]


def cli_add(daemon, capsys, path: Path, name: str) -> tuple[int, list[str]]:
    """``nurbsmotion programs add PATH --name NAME``: exit code and its error messages (prefix off)."""
    code = main(["programs", "add", str(path), "--name", name, "--socket", str(daemon.config.control.socket)])
    prefix = "nurbsmotion programs: error: "
    return code, [line.removeprefix(prefix) for line in capsys.readouterr().err.splitlines()]


def library(daemon) -> dict[str, dict[str, Any]]:
    return {meta["name"]: meta for meta in daemon.programs.library.listing()}


def uploads_open() -> int:
    """This process's descriptors of an upload's unnamed file (web.upload)."""
    names = []
    for fd in os.listdir("/proc/self/fd"):
        try:
            names.append(os.readlink(f"/proc/self/fd/{fd}"))
        except OSError:
            continue
    return sum(name.startswith(f"/memfd:{MEMFD_NAME}") for name in names)


def nothing_left_behind(daemon) -> None:
    assert uploads_open() == 0
    spool = Path(daemon.config.data_dir) / "spool"
    assert not list(spool.glob("*")) if spool.is_dir() else True


def test_an_upload_is_the_same_library_entry_as_programs_add(daemon, tmp_path: Path, capsys):
    path = tmp_path / "part.nc"
    path.write_bytes(BOM + "".join(zigzag_lines(2000)).encode())
    assert cli_add(daemon, capsys, path, "by-cli.nc") == (0, [])

    async def body(base: str, s: aiohttp.ClientSession) -> None:
        status, added = await get_json(s, "POST", f"{base}/api/v1/programs?name=by-web.nc", data=path.read_bytes())
        assert status == 200, added
    run(daemon, body)
    entries = library(daemon)
    cli, web = entries["by-cli.nc"], entries["by-web.nc"]
    assert (web["sha256"], web["size_bytes"]) == (cli["sha256"], cli["size_bytes"])
    assert web["size_bytes"] == path.stat().st_size - len(BOM)
    assert web["check"] == cli["check"] and web["check"]["blocks"] == 2000
    assert (Path(daemon.config.data_dir) / "programs" / "by-web.nc").read_bytes() == path.read_bytes()[len(BOM):]
    nothing_left_behind(daemon)


def test_a_raw_job_upload_runs_from_the_file(daemon):
    async def body(base: str, s: aiohttp.ClientSession) -> str:
        status, job = await get_json(s, "POST", f"{base}/api/v1/jobs?name=short.nc&start_line=2",
                                     data=b"G21 G90 F3000\nG01 X1\nG01 X0\n")
        assert status == 200, job
        return str(job["job"]["id"])
    job_id = run(daemon, body)
    last = idle_after(daemon, job_id)
    assert (last["name"], last["outcome"]) == ("short.nc", "completed")
    nothing_left_behind(daemon)


def resident_bytes() -> int:
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise AssertionError("no VmRSS in /proc/self/status")


class PeakResident:
    """This process's highest resident size while the block runs, sampled every 2 ms."""

    def __init__(self) -> None:
        self.peak_bytes = 0
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self) -> None:
        while not self._done.is_set():
            self.peak_bytes = max(self.peak_bytes, resident_bytes())
            time.sleep(0.002)

    def __enter__(self) -> "PeakResident":
        self._thread.start()
        return self

    def __exit__(self, *_: Any) -> None:
        self._done.set()
        self._thread.join()


def test_a_million_line_upload_is_added_without_a_copy_in_the_process(daemon):
    lines = zigzag_lines(1_000_000)
    size_bytes = sum(len(line) for line in lines)

    async def chunks() -> AsyncIterator[bytes]:  # sent chunked (no Content-Length), never whole here
        for start in range(0, len(lines), 4096):
            yield "".join(lines[start:start + 4096]).encode()

    async def body(base: str, s: aiohttp.ClientSession) -> int:
        await get_json(s, "POST", f"{base}/api/v1/programs?name=warm.nc", data=b"G21\nG01 X1 F3000\n")
        before = resident_bytes()
        with PeakResident() as peak:
            status, added = await get_json(s, "POST", f"{base}/api/v1/programs?name=million.nc", data=chunks())
        assert status == 200, added
        assert added["program"]["size_bytes"] == size_bytes and added["program"]["check"]["blocks"] == 1_000_000
        return peak.peak_bytes - before
    growth_bytes = run(daemon, body)
    # gateway and daemon (both in this process) stream it: 3.7-3.9 MB of chunks and buffers,
    # where one whole copy of the 13.4 MB body (bytes or str) anywhere would add its size
    # (the gateway that held it as bytes, str and JSON text grew this process by 120 MB)
    assert growth_bytes < size_bytes, f"grew {growth_bytes / 2**20:.1f} MB for a {size_bytes / 2**20:.1f} MB body"
    nothing_left_behind(daemon)


def test_bad_uploads_get_the_clis_lines_and_change_nothing(daemon, tmp_path: Path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cases = {"latin1.nc": BOM + b"G21\nG01 X1 F3000 (caf\xe9)\n",  # 400: the byte is named as the CLI names it
             "empty.nc": b"",  # 422: the daemon's check, as for the CLI's empty file
             "refused.nc": b"G21 G90\nG01 X4 Q1 F3000\nG01 X500\n"}  # 422: one line per error
    for name, data in cases.items():
        Path(name).write_bytes(data)
    before = library(daemon)
    cli_lines = {name: cli_add(daemon, capsys, Path(name), name) for name in cases}

    async def body(base: str, s: aiohttp.ClientSession) -> None:
        for name, data in cases.items():
            status, answer = await get_json(s, "POST", f"{base}/api/v1/programs?name={name}", data=data)
            assert status == (400 if name == "latin1.nc" else 422), answer
            assert answer.get("errors", [answer["error"]]) == cli_lines[name][1], name
        byte = cases["latin1.nc"].index(b"\xe9")  # counted from the file's start, its byte-order mark too
        assert cli_lines["latin1.nc"][1] == [f"latin1.nc: not a UTF-8 text file (invalid continuation byte at byte {byte})"]
        for path in ("/api/v1/programs?name=../x.nc", "/api/v1/programs"):
            status, answer = await get_json(s, "POST", base + path, data=b"G21\nG01 X1 F3000\n")
            assert status == 400 and "program name" in answer["error"], answer
    run(daemon, body)
    assert library(daemon) == before
    nothing_left_behind(daemon)


async def endless(chunk: bytes, count: int) -> AsyncIterator[bytes]:
    for _ in range(count):
        yield chunk


@pytest.mark.parametrize("how", ["declared", "chunked"])
def test_an_upload_over_the_limit_is_413_with_nothing_left_behind(daemon, how: str):
    chunk = b"G01 X1 Y1\n" * 10_000  # 100 kB
    before = library(daemon)

    async def body(base: str, s: aiohttp.ClientSession) -> None:
        data = chunk * 40 if how == "declared" else endless(chunk, 40)  # 4 MB against a 1 MB limit
        status, answer = await get_json(s, "POST", f"{base}/api/v1/programs?name=big.nc", data=data)
        assert status == 413, answer
        assert answer == {"error": "upload larger than the 1 MB limit (web.max_upload_mb)"}
        status, _ = await get_json(s, "GET", f"{base}/api/v1/status")  # the gateway serves on
        assert status == 200
    run(daemon, body, max_upload_bytes=1 << 20)
    assert library(daemon) == before
    nothing_left_behind(daemon)
