"""`nurbsmotion check` of real CAM programs of 10^4, 10^5 and 10^6 lines: time and peak memory
(issue 25: 1,000,000 lines checked in <= 10 s and <= 500 MB).

Inputs are real corpus programs repeated to the size (generated into a temporary folder,
not committed): grbl's HSM_test.nc (pocketing, short G01 moves) and a Fusion 360 program
(fusion360_led_floor_1121_btn8copies_20bit.nc: G01 and G02/G03 helices, a third of its lines
arcs), each copy without its program end, one M30 at the end. Each run is a fresh
`nurbsmotion check FILE` process (start-up and imports included): wall time, CPU time
(user + system) and peak RSS from os.wait4. ``--old-src DIR`` also runs the reader of
another checkout (e.g. /work/main/src, before the records) on the sizes up to
``--old-max-lines``.

Run: python benchmarks/bench_check.py [--sizes 10000 100000 1000000] [--old-src DIR] [--write]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._report import write_section  # noqa: E402

CORPUS = ROOT / "tests" / "data" / "gcode"
PROGRAMS = {"HSM_test": CORPUS / "grbl_HSM_test.nc", "Fusion 360": CORPUS / "fusion360_led_floor_1121_btn8copies_20bit.nc"}
ENDS = {"M30", "M2", "M02", "%"}
TARGET_S, TARGET_MB = 10.0, 500.0  # issue 25, for 1,000,000 lines


@dataclass(frozen=True)
class Run:
    wall_s: float
    cpu_s: float
    peak_mb: float
    ok: bool


def repeated(source: Path, lines: int, folder: Path) -> Path:
    """``source`` repeated to ``lines`` lines, without its program ends, then M30."""
    body = [ln for ln in source.read_text().rstrip("\n").split("\n") if ln.strip().upper() not in ENDS]
    out: list[str] = []
    while len(out) < lines - 1:
        out.extend(body)
    path = folder / f"{source.stem}_x_{lines}.nc"
    path.write_text("\n".join(out[:lines - 1] + ["M30"]) + "\n")
    return path


def check_once(program: Path, src: Path) -> Run:
    """One `nurbsmotion check` process with ``src`` first on sys.path."""
    code = f"import sys; sys.path.insert(0, {str(src)!r}); from nurbsmotion.__main__ import main; sys.exit(main())"
    start = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-c", code, "check", str(program)], stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE)
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - start
    process.returncode = os.waitstatus_to_exitcode(status)
    return Run(wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024.0, process.returncode == 0)


def best_of(repeat: int, program: Path, src: Path) -> Run:
    runs = [check_once(program, src) for _ in range(repeat)]
    return Run(min(r.wall_s for r in runs), min(r.cpu_s for r in runs), max(r.peak_mb for r in runs), all(r.ok for r in runs))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--repeat", type=int, default=1, help="runs per case (best time, largest memory)")
    parser.add_argument("--old-src", type=Path, help="src/ of another checkout to compare (the reader before)")
    parser.add_argument("--old-max-lines", type=int, default=100_000)
    parser.add_argument("--write", action="store_true", help="rewrite the section of docs/benchmarks.md")
    args = parser.parse_args()
    rows, headline = [], []
    with tempfile.TemporaryDirectory(prefix="bench_check_") as tmp:
        for name, source in PROGRAMS.items():
            for size in args.sizes:
                program = repeated(source, size, Path(tmp))
                readers = [("records + fast path", ROOT / "src")]
                if args.old_src is not None and size <= args.old_max_lines:
                    readers.append(("before (NURBS per line)", args.old_src))
                for reader, src in readers:
                    run = best_of(args.repeat, program, src)
                    rows.append(f"| {name} x {size:,} lines | {reader} | {run.wall_s:.2f} s | {run.cpu_s:.2f} s | "
                                f"{run.peak_mb:.0f} MB | {'ok' if run.ok else 'FAILED'} |")
                    print(rows[-1], flush=True)
                    if size == max(args.sizes) and src == ROOT / "src":
                        met = run.cpu_s <= TARGET_S and run.peak_mb <= TARGET_MB
                        headline.append(f"| {name} | **{run.cpu_s:.1f} s** | {run.wall_s:.1f} s | **{run.peak_mb:.0f} MB** | "
                                        f"<= {TARGET_S:g} s, <= {TARGET_MB:g} MB: {'met' if met else 'NOT met'} (CPU) |")
    one, five, fifteen = os.getloadavg()
    body = (f"| {max(args.sizes):,} lines | CPU (user + system) | wall | peak RSS | target (issue 25) |\n|---|---|---|---|---|\n"
            + "\n".join(headline) + "\n\n"
            f"Each run a fresh `nurbsmotion check FILE` process (start-up, imports, reading, summary). Host load average "
            f"{one:.1f} / {five:.1f} / {fifteen:.1f} (1/5/15 min) at the end; 2 cores shared with other sessions: wall "
            "time counts the wait for a core, CPU time what the check costs.\n\n"
            "| program | reader | wall | CPU | peak RSS | check |\n|---|---|---|---|---|---|\n" + "\n".join(rows))
    if args.write:
        write_section("check", "`nurbsmotion check` of long CAM programs", body, "python benchmarks/bench_check.py "
                      + " ".join(sys.argv[1:]))
    else:
        print(body)


if __name__ == "__main__":
    main()
