"""Short-segment smoothing speed (geometry/polyline_fit.py): G01 chains -> smoothable_runs ->
fit_run at 0.01 mm, in input vertices per second. Target (issue 24): >= 100,000 vertices/s.

Cases: real CAM programs (tests/data/gcode: grbl_HSM_test.nc, braid_cut2d.nc adapted as
bench_plan_command does, and the corpus' largest smooth-surface programs) and a synthetic
spiral of 100,000 chords of 0.1 mm with 3 um noise. Times are the best of R runs, as CPU time
of this process (what the code costs, whatever else runs on the host) and as wall time (what
a user waits on this host now). Not timed: max_deviation of every fit, reported as the largest.

Run: python benchmarks/bench_polyline_fit.py [--repeat R] [--spiral N]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Callable

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import write_section  # noqa: E402
from benchmarks.bench_plan_command import braid_text  # noqa: E402
from benchmarks.bench_program import CORPUS, CORPUS_TOOLS, best_cpu_and_wall  # noqa: E402
from nurbsmotion.geometry.polyline_fit import max_deviation, smooth_polyline  # noqa: E402
from nurbsmotion.program import ReadOptions, parse_gcode, parse_tool_table, read_program  # noqa: E402
from nurbsmotion.program.line_chains import line_chains  # noqa: E402

TOLERANCE_MM = 0.01
PROGRAMS = ["grbl_HSM_test.nc", "grbl_miller.gcode", "linuxcnc_tp_wheels.ngc", "camotics_tiny_cat_outline.ngc",
            "linuxcnc_tp_LHchips4.ngc", "camotics_bear.nc"]

Chain = tuple[np.ndarray, np.ndarray | None, np.ndarray | None]  # points, feeds per segment, breaks per vertex


def program_chains(name: str) -> list[Chain]:
    tools = ReadOptions(tool_table=parse_tool_table(CORPUS_TOOLS, "bench_tools.yaml"))
    program = read_program(CORPUS / name, options=tools)
    return [(c.points, c.feeds_mm_s, c.breaks) for c in line_chains(program)]


def braid_chains() -> list[Chain]:
    return [(c.points, c.feeds_mm_s, c.breaks) for c in line_chains(parse_gcode(braid_text(), "braid_cut2d.nc"))]


def spiral_chain(n: int) -> list[Chain]:
    """An Archimedean spiral of n chords of about 0.1 mm from r = 5 mm, 3 um noise per coordinate."""
    s = np.arange(n + 1) * 0.1
    r = np.sqrt(25.0 + s / np.pi)  # pitch 1 mm: r = 5 + angle / (2 pi), ds = r d(angle), so r^2 = 25 + s / pi
    angle = 2.0 * np.pi * (r - 5.0)
    points = np.column_stack([r * np.cos(angle), r * np.sin(angle), np.zeros(n + 1)])
    points[1:-1, :2] += np.random.default_rng(7).uniform(-0.003, 0.003, (n - 1, 2))
    return [(points, None, None)]


def smooth_all(chains: list[Chain]) -> Callable[[], tuple[list, int]]:
    """(fits as (vertices, curve), runs kept as lines) of all chains."""
    def run() -> tuple[list, int]:
        fits, kept = [], 0
        for points, feeds, breaks in chains:
            result = smooth_polyline(points, TOLERANCE_MM, feeds, breaks)
            fits += [(fit.span.vertices(points), fit.curve) for fit in result.fitted]
            kept += len(result.kept)
        return fits, kept
    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--spiral", type=int, default=100_000)
    args = parser.parse_args()
    cases = [(name, program_chains(name)) for name in PROGRAMS]
    cases.insert(1, ("braid_cut2d.nc (test_no_give_ups' adaptation)", braid_chains()))
    cases.append((f"synthetic spiral, {args.spiral:,} chords of 0.1 mm, 3 um noise", spiral_chain(args.spiral)))
    rows = []
    for title, chains in cases:
        vertices = sum(len(points) for points, _, _ in chains)
        run = smooth_all(chains)
        fits, kept = run()
        cpu_s, wall_s = best_cpu_and_wall(args.repeat, run)
        run_vertices = sum(len(v) for v, _ in fits)
        control = sum(len(c.control_points) for _, c in fits)
        worst = max((max_deviation(c, v).max_mm for v, c in fits), default=0.0)
        rows.append(f"| {title} | {vertices:,} | {len(fits):,} | {kept:,} | {run_vertices:,} | {control:,} | "
                    f"{worst * 1000:.2f} um | {cpu_s * 1e3:.0f} ms | {wall_s * 1e3:.0f} ms | "
                    f"{vertices / cpu_s:,.0f} |")
        print(rows[-1], flush=True)
    one, five, fifteen = os.getloadavg()
    body = (f"G01 chains -> `smoothable_runs` (defaults: segments < 5 mm, turns < 30 deg, chord bulge l theta / 8 < the tolerance) -> `fit_run` at "
            f"{TOLERANCE_MM * 1000:g} um. Best of {args.repeat} runs each, as this process' CPU time and as wall time; "
            f"host load average {one:.1f} / {five:.1f} / {fifteen:.1f} (1/5/15 min) at the end (2 cores shared with "
            "other sessions). Vertices: all G01 vertices of the program; runs fitted and their vertices; runs kept: "
            "found but left as lines (no fit within vertices + 8 control points); "
            "deviation: the largest `max_deviation` of all fits (not timed). Target: 100,000 vertices/s. "
            "camotics_tiny_cat_outline.ngc runs in G61 (exact stop): every vertex is a stop, nothing to smooth.\n\n"
            "| input | G01 vertices | runs fitted | runs kept | fitted vertices | control points | largest deviation | "
            "CPU time | wall time | vertices/s (CPU) |\n|---|---|---|---|---|---|---|---|---|---|\n" + "\n".join(rows))
    write_section("polyline_fit", "Short-segment smoothing", body, "python benchmarks/bench_polyline_fit.py")


if __name__ == "__main__":
    main()
