"""CPU and wall time to the planner's first chunk (PlanStream, chunk 2000, first chunk 200
cycles, as a streaming job plans) of a real CAM program repeated, and the whole plan's
set-points per second (issue 25 part 4: the set-up section by section).

T = 1 ms, A = 2500 mm/s^2, J = 50000 mm/s^3, F = 200 mm/s, chord 1 um, corner blending and
smoothing at the default 0.01 mm. ``--src DIR``: plan with another checkout's src (the
"before" column). Reading the program is not counted.

Run: python benchmarks/bench_first_chunk.py [--program FILE] [--copies 2 19] [--whole] [--src DIR]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--program", default=str(ROOT / "tests/data/gcode/fusion360_led_floor_1121_btn8copies_20bit.nc"))
    parser.add_argument("--copies", type=int, nargs="*", default=[2, 19])
    parser.add_argument("--whole", action="store_true", help="also plan every chunk (set-points/s)")
    parser.add_argument("--src", default=str(ROOT / "src"))
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    from benchmarks.bench_first_motion import program_copies  # puts this checkout's src first: --src goes before it

    sys.path.insert(0, args.src)
    from nurbsmotion.planning import PlanLimits
    from nurbsmotion.planning.lookahead.api import PlanStream
    from nurbsmotion.program import read_program

    assert Path(sys.modules[PlanStream.__module__].__file__ or "").is_relative_to(Path(args.src).resolve())

    limits = PlanLimits(period_s=0.001, chord_error_mm=0.001, max_accel_mm_s2=2500.0, max_jerk_mm_s3=50000.0,
                        feed_mm_s=200.0, rapid_feed_mm_s=200.0)
    print("| lines | blocks | first chunk CPU s | wall s | whole plan set-points/s (CPU) |")
    print("|---:|---:|---:|---:|---:|")
    for copies in args.copies:
        with tempfile.TemporaryDirectory() as work:
            path = Path(work) / "program.nc"
            text = program_copies(Path(args.program), copies)
            path.write_text(text)
            program = read_program(path)
        cpu, wall = time.process_time(), time.perf_counter()
        chunks = PlanStream(program, limits, 2000, 200).chunks()
        first, _ = next(chunks)
        cpu_first, wall_first = time.process_time() - cpu, time.perf_counter() - wall
        rate = ""
        if args.whole:
            points = len(first.u) + sum(len(c.u) for c, _ in chunks)
            rate = f"{points / (time.process_time() - cpu):,.0f}"
        print(f"| {text.count(chr(10)):,} | {len(program.blocks):,} | {cpu_first:.3f} | {wall_first:.3f} | {rate} |",
              flush=True)


if __name__ == "__main__":
    main()
