"""Motion time of the lookahead planner against a continuous lower bound, and how much of
the allowed chord error it uses where chord error limits the speed.

The lower bound is the time-optimal continuous motion (no jerk limit, no sampling) along
the same runs (the planner's exact stops and junction speeds, runs.py), under the same
limits at 100 % (the planner plans at 99.5 %): v <= F, the chord-error speed
v <= sqrt(8 delta / kappa) / T with kappa the curvature at the point (not its maximum
over a step), centripetal kappa v^2 <= A, tangential a_t^2 + (kappa v^2)^2 <= A^2 and the
per-axis velocity limits; a forward-backward scan in v^2 on a 5 um arc-length grid. Every
relaxation is on the fast side: caps only at grid points, each interval's tangential
acceleration from its looser end, and the fixed point of the speed-dependent scan
approached from above (an even iterate, scan.py). It is a bound for the planner's figure:
every plan of the same runs within the same limits takes at least this long (up to the
grid's resolution).

Where chord error can limit the speed at all: a step of length v T on curvature kappa
deviates kappa (v T)^2 / 8 from its chord, and kappa v^2 <= A, so the chord error of any
plan within the acceleration limit is at most A T^2 / 8 (0.31 um at A = 2500 mm/s^2,
T = 1 ms). Only where delta < A T^2 / 8 can the chord error limit the speed.

Run: python benchmarks/bench_motion_time.py [--previous-src ../main/src]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))

from benchmarks._report import write_section  # noqa: E402
from nurbsmotion.planning import PlanLimits  # noqa: E402
from nurbsmotion.planning.lookahead import plan_lookahead  # noqa: E402
from nurbsmotion.planning.lookahead.path import build_grid  # noqa: E402
from nurbsmotion.planning.lookahead.planner import settings_for  # noqa: E402
from nurbsmotion.planning.lookahead.api import planned_pieces  # noqa: E402
from nurbsmotion.planning.lookahead.runs import ProgramStops, split_runs  # noqa: E402
from nurbsmotion.planning.measure import measure  # noqa: E402
from nurbsmotion.program import Program, parse_gcode, read_program  # noqa: E402

GRID_MM = 0.005
BUTTERFLY = ROOT / "tests" / "data" / "gcode" / "linuxcnc_nurbs_G5_butterfly-xy.ngc"
SCAN_ROUNDS = 40


def run_lower_bound(run, limits: PlanLimits) -> float:
    """Time-optimal continuous motion along one run, rest to rest (module docstring)."""
    grid = build_grid(run.pieces, GRID_MM)
    kappa = np.linalg.norm(grid.curv, axis=1)
    a_max, period = limits.max_accel_mm_s2, limits.period_s
    with np.errstate(divide="ignore"):
        v = np.minimum(grid.feed_mm_s, np.sqrt(a_max / kappa))
        v = np.minimum(v, np.sqrt(8.0 * limits.chord_error_mm / kappa) / period)
    tangent = np.abs(grid.tangent)
    if limits.axis_max_velocity_mm_s is not None:
        vmax = np.full(3, np.inf)
        vmax[: len(limits.axis_max_velocity_mm_s)] = limits.axis_max_velocity_mm_s
        with np.errstate(divide="ignore"):
            v = np.minimum(v, (vmax / tangent).min(axis=1))
    ends = np.flatnonzero(grid.junction)
    for i, vj in zip(ends, run.junction_speed_mm_s):
        v[i], v[i + 1] = min(v[i], vj), min(v[i + 1], vj)
    cap = v**2
    cap[0] = cap[-1] = 0.0
    ds = np.diff(grid.s)
    y = cap.copy()
    for _ in range(SCAN_ROUNDS):  # pairs of scans: y stays an even iterate, >= the optimum (see scan.py)
        for _ in range(2):
            normal = kappa * y
            a_t = np.sqrt(np.maximum(a_max**2 - normal**2, 0.0))
            a_int = np.maximum(a_t[:-1], a_t[1:])  # the looser end of each interval: a relaxation
            back = np.concatenate([[0.0], np.cumsum(2.0 * a_int * ds)])
            x = np.minimum.accumulate((cap + back)[::-1])[::-1] - back
            y = np.maximum(back + np.minimum.accumulate(x - back), 0.0)
    x = y
    speed = np.sqrt(x)
    mean = 0.5 * (speed[:-1] + speed[1:])
    return float(np.sum(np.where(mean > 0, ds / np.where(mean > 0, mean, 1.0), 0.0)))


def lower_bound(program: Program, limits: PlanLimits) -> float:
    pieces = planned_pieces(program, limits)  # the path the planner plans along (corners blended)
    settings = settings_for(limits, max(p.feed_mm_s for p in pieces), 20000)
    runs = split_runs(pieces, limits, settings.min_pass_mm_s, ProgramStops.of(program, limits))
    return sum(run_lower_bound(run, limits) for run in runs)


JERK_MM_S3 = 50000.0
# (T ms, delta um, J mm/s^3 or None): the paper's setting without a jerk limit (the lower bound
# has none), then the default planner's with one (the bound is then weaker: it ignores J)
CASES = tuple((period_ms, delta_um, jerk) for jerk in (None, JERK_MM_S3)
              for period_ms, delta_um in ((1, 1.0), (1, 0.1), (4, 10.0), (4, 1.0)))
PREVIOUS_SCRIPT = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
from nurbsmotion.planning import PlanLimits
from nurbsmotion.planning.lookahead import plan_lookahead
from nurbsmotion.program import parse_gcode, read_program
out = []
for kind, source, name in json.loads(sys.argv[2]):
    program = read_program(source) if kind == "file" else parse_gcode(source, name)
    for period_ms, delta_um, jerk in json.loads(sys.argv[3]):
        limits = PlanLimits(period_s=period_ms / 1000.0, chord_error_mm=delta_um / 1000.0, feed_mm_s=200.0,
                            max_jerk_mm_s3=jerk)
        out.append((len(plan_lookahead(program, limits)) - 1) * limits.period_s)
print(json.dumps(out))
"""


def previous_times(src: str | None, sources: list[tuple[str, str, str]]) -> list[float | None]:
    """Motion times of the planner in another checkout's src (the previous version), same cases."""
    if not src:
        return [None] * (len(sources) * len(CASES))
    out = subprocess.run([sys.executable, "-c", PREVIOUS_SCRIPT, src, json.dumps(sources), json.dumps(CASES)],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def rows(programs: dict[str, Program], previous: list[float | None]) -> str:
    out = ["| program | J mm/s^3 | T ms | delta um | A T^2/8 um | limits the speed | verified max chord / delta "
           "| measured max chord / delta | motion s (previous) | motion s | change | lower bound s | ratio (previous) "
           "| ratio |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    before = iter(previous)
    bounds: dict[tuple[str, int, float], float] = {}
    for name, program in programs.items():
        for period_ms, delta_um, jerk in CASES:
            limits = PlanLimits(period_s=period_ms / 1000.0, chord_error_mm=delta_um / 1000.0, feed_mm_s=200.0,
                                max_jerk_mm_s3=jerk)
            trajectory = plan_lookahead(program, limits)
            m = measure(trajectory, program)
            ceiling = limits.max_accel_mm_s2 * limits.period_s**2 / 8.0 * 1000.0
            binds = "chord error can" if delta_um < ceiling else "acceleration (chord error cannot)"
            key = (name, period_ms, delta_um)
            if key not in bounds:  # the bound has no jerk limit: the same for both rows
                bounds[key] = lower_bound(program, limits)
            bound = bounds[key]
            verified = trajectory.notes["verified_max_chord_error_mm"] * 1000.0 / delta_um
            old = next(before)
            old_text = ((f"{old:.3f}", f"{(m.duration_s / old - 1.0) * 100.0:+.1f} %", f"{old / bound:.3f}")
                        if old is not None else ("-", "-", "-"))
            out.append(f"| {name} | {'-' if jerk is None else f'{jerk:g}'} | {period_ms} | {delta_um:g} | "
                       f"{ceiling:.3g} | {binds} | {verified:.3f} | {m.max_chord_error_mm * 1000.0 / delta_um:.3f} | "
                       f"{old_text[0]} | {m.duration_s:.3f} | {old_text[1]} | {bound:.3f} | {old_text[2]} | "
                       f"{m.duration_s / bound:.3f} |")
    return "\n".join(out)



def summary(table: str) -> str:
    """The T = 1 ms, delta = 1 um rows of ``table``: motion time against the bound, without and with J."""
    out = ["| program (T = 1 ms, delta = 1 um) | J mm/s^3 | motion s | lower bound s | ratio |", "|---|---|---|---|---|"]
    for line in table.splitlines()[2:]:
        cells = [c.strip() for c in line.strip("|").split("|")]
        if cells[2] == "1" and cells[3] == "1":
            out.append(f"| {cells[0]} | {cells[1]} | {cells[9]} | {cells[11]} | {cells[13]} |")
    return "\n".join(out)


def butterfly_text() -> str | None:
    """LinuxCNC's nc_files/nurbs/G5/butterfly-xy.ngc (G5.2 NURBS) from the G-code corpus
    (tests/data/gcode/SOURCES.md)."""
    return BUTTERFLY.read_text() if BUTTERFLY.exists() else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--previous-src", metavar="DIR", help="src/ of a checkout of the previous version, for its motion times")
    args = parser.parse_args()
    sources = [("file", str(ROOT / "examples" / "wang_table1.nc"), "Wang Table 1"),
               ("file", str(ROOT / "examples" / "sharp_corners.yaml"), "sharp corners")]
    text = butterfly_text()
    if text is not None:
        sources.append(("text", text, BUTTERFLY.name))
    programs = {name if kind == "file" else "LinuxCNC butterfly (G5.2)":
                read_program(source) if kind == "file" else parse_gcode(source, name) for kind, source, name in sources}
    previous = previous_times(args.previous_src, sources)
    table = rows(programs, previous)
    body = f"""
F = 200 mm/s (12 m/min) for every block, A = 2500 mm/s^2, PlanLimits defaults otherwise; without a
jerk limit (as the lower bound) and with J = {JERK_MM_S3:g} mm/s^3 (the default planner's usual
setting; the lower bound ignores J, so those ratios include what the jerk limit costs). "limits
the speed": chord error can only limit where delta < A T^2 / 8 (see the benchmark's docstring).
Lower bound: continuous time-optimal motion along the same runs at 100 % of the limits,
{GRID_MM * 1000:g} um grid. Motion times are deterministic (no timing involved).

{table}

"previous" is the planner before this change (the --previous-src checkout), "change" the motion
time against it, "ratio" the motion time over the lower bound.

Chord error used (issue 17, deliverable 4, target >= 0.8 delta where chord error limits the
speed): wherever delta < A T^2 / 8 the verified chord error is 0.98-1.00 delta on Wang's curve and
the butterfly, with and without J (measured on the true curve by planning.measure: 0.98-0.99;
tests/planning/lookahead/test_chord_bound.py asserts >= 0.8 for these cases). The issue's 0.31 um
of 1 um on the butterfly at T = 1 ms is the acceleration limit, not the bound: a step v T on
curvature kappa sags kappa (v T)^2 / 8 <= A T^2 / 8 = 0.31 um whenever kappa v^2 <= A, so no plan
within A can use more there. With J the butterfly at T = 1 ms, delta = 1 um uses only 0.11: the
path's own jerk (v^3 |c|^2 and the normal terms) limits the speed before chord error does.

The sharp-corner program (a near-cusp zigzag) turns within less than a step at T = 4 ms: the
planner has to shorten the steps across the whole turn, which the bound (curvature at points, no
steps) does not see; how much of its 1.9-4x is the bound's weakness and how much the plan's was
not examined.
"""
    write_section("motion_time", "Motion time against a continuous lower bound; chord error used",
                  "F = 200 mm/s, A = 2500 mm/s^2; the bound: continuous time-optimal motion without J along the "
                  "same path (deterministic, no timing).\n\n" + summary(table),
                  "python benchmarks/bench_motion_time.py", detail=body)


if __name__ == "__main__":
    main()
