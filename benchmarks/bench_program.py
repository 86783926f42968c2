"""Program reading speed: G-code lines, arcs and NURBS blocks, YAML curves, per line.

Run: python benchmarks/bench_program.py [--lines N] [--repeat R]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import write_section  # noqa: E402
from benchmarks.bench_geometry import best_of  # noqa: E402
from nurbsmotion.program import parse_curve_yaml, parse_gcode  # noqa: E402

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


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
    cases = [
        (f"{n:,} G01 lines", lines_program(n), parse_gcode, n + 1),
        (f"{n:,} G02/G03 arcs (2/3 IJK, 1/3 R)", arcs_program(n), parse_gcode, n + 1),
        (f"one G06.2 cubic NURBS, {n:,} control points", nurbs_program(n), parse_gcode, n + 5),
        ("Wang Table 1 (examples/wang_table1.nc)", (EXAMPLES / "wang_table1.nc").read_text(), parse_gcode, 25),
        ("Wang Table 1 (examples/wang_table1.yaml)", (EXAMPLES / "wang_table1.yaml").read_text(), parse_curve_yaml, 25),
    ]
    rows = []
    for title, text, parse, n_lines in cases:
        seconds = best_of(args.repeat, lambda: parse(text, "bench"))
        rows.append(f"| {title} | {seconds * 1e3:.1f} ms | {seconds / n_lines * 1e6:.1f} us |")
    body = "| program (parse + validate + build curves) | total (best of {r}) | per line |\n|---|---|---|\n".format(
        r=args.repeat) + "\n".join(rows)
    print(body)
    write_section("program", "Program reading", body, "python benchmarks/bench_program.py")


if __name__ == "__main__":
    main()
