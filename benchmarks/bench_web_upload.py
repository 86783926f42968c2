"""Memory of a large program upload through the web gateway: the daemon and ``nurbsmotion web``
as separate processes (bench_web.Running), the program sent chunked from this process.

    python benchmarks/bench_web_upload.py --lines 1000000 --previous-src /tmp/main/src

For each checkout (this one; with ``--previous-src`` also the previous one, alternating round
by round) a fresh daemon and gateway get ``POST /api/v1/programs?name=...`` of an N-line
program; the figures are each process's peak resident size (``VmHWM``) before and after, and
the upload's wall time (the daemon's check in its own process included). Printed only: the
result goes into docs/benchmarks.md's section "Web upload" by hand.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import time
from pathlib import Path
from typing import Any, AsyncIterator

import aiohttp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.bench_web import SRC, Running  # noqa: E402

MB = 1024 * 1024


def peak_resident_bytes(pid: int) -> int:
    """``VmHWM`` of /proc/PID/status: the process's highest resident size so far."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise RuntimeError(f"no VmHWM for pid {pid}")


def program_line(i: int) -> str:
    return f"G01 X{(i % 50) * 0.1:.1f} Y{(i % 7) * 0.2:.1f}\n"


async def program_chunks(lines: int) -> AsyncIterator[bytes]:
    """The N-line program, 4096 lines a chunk (never whole in this process either)."""
    yield b"G21 G90 F3000\n"
    for start in range(1, lines + 1, 4096):
        yield "".join(program_line(i) for i in range(start, min(start + 4096, lines + 1))).encode()


async def upload_round(src: Path, lines: int) -> dict[str, Any]:
    running = Running(src)
    try:
        await running.start()
        pids = running.pids
        async with aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=600)) as session:
            async with session.post(f"{running.base}/api/v1/programs?name=warm.nc", data=b"G21\nG01 X1 F3000\n") as r:
                await r.read()
            before = {name: peak_resident_bytes(pid) for name, pid in pids.items()}
            t0 = time.monotonic()
            async with session.post(f"{running.base}/api/v1/programs?name=big.nc", data=program_chunks(lines)) as r:
                answer = await r.json()
                status = r.status
            wall_s = time.monotonic() - t0
            after = {name: peak_resident_bytes(pid) for name, pid in pids.items()}
        if status != 200:
            raise RuntimeError(f"upload refused: {status} {answer}")
        return {"size_mb": answer["program"]["size_bytes"] / MB, "wall_s": wall_s,
                **{f"{name}_before_mb": before[name] / MB for name in pids},
                **{f"{name}_after_mb": after[name] / MB for name in pids}}
    finally:
        running.stop()


async def main_async(args: argparse.Namespace) -> list[tuple[str, dict[str, Any]]]:
    checkouts = [("this", SRC)] + ([("previous", args.previous_src)] if args.previous_src is not None else [])
    rows = []
    for _ in range(args.rounds):
        for label, src in checkouts:
            rows.append((label, await upload_round(src, args.lines)))
            print(label, rows[-1][1], flush=True)
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=1_000_000)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--previous-src", type=Path, help="src/ of a previous checkout (with its eds/ beside it)")
    args = parser.parse_args()
    rows = asyncio.run(main_async(args))
    load = " / ".join(Path("/proc/loadavg").read_text().split()[:3])
    print(f"\n{args.lines:,}-line upload; load average at the end {load}\n")
    print("| checkout | body MB | gateway peak RSS MB before -> after | daemon peak RSS MB before -> after | wall s |")
    print("|---|---|---|---|---|")
    for label, r in rows:
        print(f"| {label} | {r['size_mb']:.1f} | {r['gateway_before_mb']:.0f} -> {r['gateway_after_mb']:.0f} | "
              f"{r['daemon_before_mb']:.0f} -> {r['daemon_after_mb']:.0f} | {r['wall_s']:.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
