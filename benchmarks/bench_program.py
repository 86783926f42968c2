"""Program reading speed: G-code lines, arcs and NURBS blocks, YAML curves, per line; the
one-hour program of bench_first_motion (Wang's curve x 460, 9,200 lines) read and checked as
the planner worker does before motion; the real CAM corpus (tests/data/gcode).

Times are the best of R runs, as CPU time of this process (what the code costs, whatever
else runs on the host) and as wall time (what a user waits on this host now).

Run: python benchmarks/bench_program.py [--lines N] [--repeat R]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path
from typing import Callable

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import write_section  # noqa: E402
from benchmarks.bench_first_motion import CONFIG  # noqa: E402
from benchmarks.bench_plan_command import wang_copies  # noqa: E402
from nurbsmotion.errors import InputError  # noqa: E402
from nurbsmotion.program import ReadOptions, parse_curve_yaml, parse_gcode, parse_tool_table  # noqa: E402
from nurbsmotion.program.reader import GCODE_SUFFIXES  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
CORPUS = ROOT / "tests" / "data" / "gcode"
CORPUS_TOOLS = "tools:\n" + "".join(f"  - {{number: {n}, length_mm: {40 + n}, diameter_mm: 6}}\n" for n in range(1, 100))


def best_cpu_and_wall(repeat: int, fn: Callable[[], object]) -> tuple[float, float]:
    """(CPU s, wall s), each the best of ``repeat`` runs."""
    cpu, wall = [], []
    for _ in range(repeat):
        c0, w0 = time.process_time(), time.perf_counter()
        fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return min(cpu), min(wall)


def checked_before_motion(text: str) -> Callable[[], object]:
    """What the planner worker does before motion: parse, then streamed_job.check_before_motion
    on bench_first_motion's machine (soft limits +-200 mm)."""
    import numpy as np

    from nurbsmotion.axes import AxisMap
    from nurbsmotion.config import parse_config
    from nurbsmotion.service.job_common import parse
    from nurbsmotion.service.path_bounds import check_before_motion

    config = parse_config(CONFIG.format(channel="bench", socket="/nonexistent/ctl.sock", data_dir="/nonexistent", extra=""),
                          "machine.yaml")
    axis_map = AxisMap.from_config(config)

    def run() -> object:
        program = parse("wang_x460.nc", text, np.zeros(3), ReadOptions())
        check_before_motion("wang_x460.nc", program, config, [0, 1, 2], axis_map)
        return program
    return run


def corpus_reader() -> tuple[Callable[[], object], int, int]:
    """Read every corpus file (accepted or refused, as `nurbsmotion check` would): (run, files, lines)."""
    tools = parse_tool_table(CORPUS_TOOLS, "corpus_tools.yaml")
    texts = [(p.name, p.read_text(errors="replace")) for p in sorted(CORPUS.iterdir()) if p.suffix.lower() in GCODE_SUFFIXES]

    def run() -> None:
        for name, text in texts:
            try:
                parse_gcode(text, name, options=ReadOptions(tool_table=tools))
            except InputError:
                pass
    return run, len(texts), sum(text.count("\n") + 1 for _, text in texts)


def lines_program(n: int) -> str:
    """A zig-zag of G01 lines (one block per line)."""
    return "G21 G90 G1 F3000\n" + "\n".join(f"N{i} X{(i % 2) * 50:g} Y{i * 0.01:.2f}" for i in range(1, n + 1))


def arcs_program(n: int) -> str:
    """Alternating G02/G03 half circles of radius 5 mm along X (IJK and R forms)."""
    out = ["G21 G90 G17 F3000"]
    for i in range(1, n + 1):
        out.append(f"G0{2 + i % 2} X{10 * i} Y0 I5 J0" if i % 3 else f"G0{2 + i % 2} X{10 * i} Y0 R5")
    return "\n".join(out)


def nurbs_program(n_points: int) -> str:
    """One cubic G06.2 NURBS through a helix-like polygon of n_points control points."""
    knots = [0.0] * 4 + [i / (n_points - 3) for i in range(1, n_points - 3)] + [1.0] * 4
    out = ["G21 G90\nG06.2 P4 K0 X0 Y0 Z0 F3000"]
    for i in range(1, n_points):
        a = i * 0.3
        out.append(f"K{knots[i]:.9f} X{20 * math.cos(a) - 20:.4f} Y{20 * math.sin(a):.4f} Z{i * 0.01:.3f} R1")
    out += [f"K{k:g}" for k in knots[n_points:]]
    return "\n".join(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=10_000)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    n = args.lines
    wang_x460 = wang_copies(460)
    corpus, corpus_files, corpus_lines = corpus_reader()
    lines, arcs, nurbs = lines_program(n), arcs_program(n), nurbs_program(n)
    wang_nc, wang_yaml = (EXAMPLES / "wang_table1.nc").read_text(), (EXAMPLES / "wang_table1.yaml").read_text()
    cases: list[tuple[str, Callable[[], object], int]] = [
        (f"{n:,} G01 lines", lambda: parse_gcode(lines, "bench"), n + 1),
        (f"{n:,} G02/G03 arcs (2/3 IJK, 1/3 R)", lambda: parse_gcode(arcs, "bench"), n + 1),
        (f"one G06.2 cubic NURBS, {n:,} control points", lambda: parse_gcode(nurbs, "bench"), n + 5),
        ("Wang Table 1 (examples/wang_table1.nc)", lambda: parse_gcode(wang_nc, "bench"), 25),
        ("Wang Table 1 (examples/wang_table1.yaml)", lambda: parse_curve_yaml(wang_yaml, "bench"), 25),
        ("Wang x 460 (bench_first_motion's one-hour program), parse", lambda: parse_gcode(wang_x460, "bench"),
         wang_x460.count("\n") + 1),
        ("Wang x 460, parse + check before motion (the planner worker's work before the first chunk)",
         checked_before_motion(wang_x460), wang_x460.count("\n") + 1),
        (f"CAM corpus (tests/data/gcode: {corpus_files} files, accepted or refused)", corpus, corpus_lines),
    ]
    rows = []
    for title, run, n_lines in cases:
        cpu_s, wall_s = best_cpu_and_wall(args.repeat, run)
        rows.append(f"| {title} | {n_lines:,} | {cpu_s * 1e3:.1f} ms | {wall_s * 1e3:.1f} ms | {cpu_s / n_lines * 1e6:.1f} us |")
        print(rows[-1], flush=True)
    one, five, fifteen = os.getloadavg()
    body = (f"Best of {args.repeat} runs each, as this process' CPU time and as wall time; host load average "
            f"{one:.1f} / {five:.1f} / {fifteen:.1f} (1/5/15 min) at the end (2 cores shared with other sessions).\n\n"
            "| program (parse + validate; NURBS built for NURBS blocks only) | lines | CPU time | wall time | CPU per line |\n"
            "|---|---|---|---|---|\n" + "\n".join(rows))
    write_section("program", "Program reading", body, "python benchmarks/bench_program.py")


if __name__ == "__main__":
    main()
