"""The lookahead planner: time-optimality (toppra, ruckig), comparison with the papers'
interpolators, throughput, and the memory of a one-hour program.

Targets (issue 4):
- per-axis velocity/acceleration limits, chord error off, no jerk: motion time <= 1.03x
  toppra's time-optimal duration on the same path, our limits holding on every cycle (and how
  far toppra's own samples exceed them between its grid points);
- jerk-limited straight line: <= 1.01x ruckig's time-optimal 1-D profile;
- >= 1,000,000 set-points per second planned on Wang's Table 1 curve at T = 1 ms, with and
  (issue 17) without a jerk limit, in the nurbsmotion process (keep_freed_memory) and, for
  the gap, a bare library call (glibc's default allocator);
- a one-hour program at T = 1 ms planned and streamed in chunks with < 500 MB.

Run: python benchmarks/bench_lookahead.py [--repeat R] [--processes P] [--hour-minutes M] [--previous-src DIR]
(M = 0 skips the one-hour run, which takes a few minutes; DIR: another checkout's src/, whose
throughput is measured alongside)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))

from benchmarks._report import write_section  # noqa: E402
from nurbsmotion.geometry import NurbsCurve  # noqa: E402
from nurbsmotion.geometry.primitives import arc_curve, line_curve  # noqa: E402
from nurbsmotion.planning import ALGORITHM_MODULES, PlanLimits, plan  # noqa: E402
from nurbsmotion.planning.lookahead import plan_lookahead  # noqa: E402
from nurbsmotion.planning.measure import measure  # noqa: E402
from nurbsmotion.program import Block, BlockKind, Program, SourceRef, read_program  # noqa: E402
from tests.conftest import WANG_KNOTS, WANG_POINTS, WANG_WEIGHTS  # noqa: E402

WANG_LIMITS = PlanLimits(period_s=0.004, chord_error_mm=0.01, max_accel_mm_s2=2500.0, feed_mm_s=200.0)
JERK_MM_S3 = 50_000.0
AXIS_V = (150.0, 150.0, 150.0)
AXIS_A = (2000.0, 2000.0, 2000.0)


def wang_program() -> Program:
    curve = NurbsCurve.create(2, WANG_POINTS, WANG_WEIGHTS, WANG_KNOTS)
    return Program("wang_table1", (Block(BlockKind.NURBS, curve, 200.0, SourceRef("wang_table1", 1)),),
                   curve.start_point)


def line_program(length_mm: float) -> Program:
    curve = line_curve((0.0, 0.0, 0.0), (length_mm, 0.0, 0.0))
    return Program("line", (Block(BlockKind.LINE, curve, None, SourceRef("line", 1)),), curve.start_point)


# ---- comparison with the papers' interpolators -------------------------------------------------
def comparison(programs: dict[str, Program]) -> str:
    rows = ["| program | algorithm | motion time s | max chord error um | max accel mm/s^2 | max jerk mm/s^3 "
            "| max fluctuation (chord) | max fluctuation (arc) | planning ms |", "|---|---|---|---|---|---|---|---|---|"]
    runs = [(name, WANG_LIMITS) for name in ALGORITHM_MODULES if name != "lookahead"]
    runs += [("lookahead", WANG_LIMITS), ("lookahead", replace(WANG_LIMITS, max_jerk_mm_s3=JERK_MM_S3))]
    for label, program in programs.items():
        for name, limits in runs:
            started = time.perf_counter()
            try:
                trajectory = plan(program, limits, name)
            except Exception as err:  # noqa: BLE001 - a benchmark reports failures as rows
                rows.append(f"| {label} | {name} | failed: {err} | | | | | | |")
                continue
            elapsed = time.perf_counter() - started
            m = measure(trajectory, program)
            shown = name + (f" (J {limits.max_jerk_mm_s3:g})" if limits.max_jerk_mm_s3 else "")
            arc = trajectory.notes.get("verified_max_arc_fluctuation")
            arc_text = f"{arc:.1e}" if isinstance(arc, float) else "-"
            rows.append(f"| {label} | {shown} | {m.duration_s:.3f} | {m.max_chord_error_mm * 1000:.2f} | "
                        f"{m.max_accel_mm_s2:.0f} | {m.max_jerk_mm_s3:.3g} | {m.max_fluctuation:.1e} | {arc_text} | "
                        f"{elapsed * 1000:.0f} |")
    return "\n".join(rows)


# ---- toppra ---------------------------------------------------------------------------------------
def toppra_comparison(period_s: float) -> str:
    try:
        import toppra
        import toppra.algorithm
        import toppra.constraint
    except ImportError as err:
        return f"toppra is not installed ({err}); `pip install toppra` to run this comparison."
    toppra.setup_logging("WARNING") if hasattr(toppra, "setup_logging") else None
    program = wang_program()
    curve = program.blocks[0].curve
    vmax, amax = np.array(AXIS_V), np.array(AXIS_A)
    limits = PlanLimits(period_s=period_s, chord_error_mm=1000.0, max_accel_mm_s2=1e7, feed_mm_s=1e4,
                        axis_max_velocity_mm_s=AXIS_V, axis_max_accel_mm_s2=AXIS_A)
    started = time.perf_counter()
    ours = plan_lookahead(program, limits)
    ours_s = time.perf_counter() - started
    m = measure(ours, program)
    ours_v = max(v / lim for v, lim in zip(m.axis_max_velocity_mm_s, vmax))
    ours_a = max(a / lim for a, lim in zip(m.axis_max_accel_mm_s2, amax))

    s = np.linspace(0.0, curve.length, 4001)
    path = toppra.SplineInterpolator(s, curve.points(curve.u_at_arc_length(s)))
    constraints = [toppra.constraint.JointVelocityConstraint(np.stack([-vmax, vmax], axis=1)),
                   toppra.constraint.JointAccelerationConstraint(np.stack([-amax, amax], axis=1))]
    started = time.perf_counter()
    instance = toppra.algorithm.TOPPRA(constraints, path, gridpoints=np.linspace(0.0, curve.length, 2001),
                                       parametrizer="ParametrizeConstAccel")
    result = instance.compute_trajectory(0, 0)
    toppra_s = time.perf_counter() - started
    duration = float(result.duration)
    t = np.arange(0.0, duration, period_s)
    samples = np.vstack([result(t), result(duration)[None, :]])
    v = np.abs(np.diff(samples, axis=0)) / period_s
    a = np.abs(np.diff(samples, 2, axis=0)) / period_s**2
    fine = np.linspace(0.0, duration, 200_001)
    cont_v = np.abs(result(fine, 1)).max(axis=0) / vmax
    cont_a = np.abs(result(fine, 2)).max(axis=0) / amax
    ratio = m.duration_s / duration
    return f"""
Wang's Table 1 curve, per-axis |v| <= {AXIS_V[0]:g} mm/s and |a| <= {AXIS_A[0]:g} mm/s^2, chord error
and resultant acceleration off, no jerk limit, T = {period_s * 1000:g} ms. toppra: TOPP-RA on a cubic spline
through 4001 points of the same curve (uniform in arc length), 2001 grid points, constant-acceleration
parametrisation.

| | motion time s | max axis v / limit | max axis a / limit | planning s |
|---|---|---|---|---|
| lookahead (every cycle measured) | {m.duration_s:.4f} | {ours_v:.4f} | {ours_a:.4f} | {ours_s:.3f} |
| toppra, sampled every cycle | {duration:.4f} | {(v.max(axis=0) / vmax).max():.4f} | {(a.max(axis=0) / amax).max():.4f} | {toppra_s:.3f} |
| toppra, continuous (200,001 samples) | | {cont_v.max():.4f} | {cont_a.max():.4f} | |

lookahead / toppra = **{ratio:.4f}** (target <= 1.03: {'met' if ratio <= 1.03 else 'NOT met'}).
"""


# ---- ruckig ---------------------------------------------------------------------------------------
def ruckig_duration(length_mm: float, v: float, a: float, j: float) -> float:
    from ruckig import InputParameter, Result, Ruckig, Trajectory

    inp = InputParameter(1)
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [0.0], [0.0]
    inp.target_position, inp.target_velocity, inp.target_acceleration = [length_mm], [0.0], [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [v], [a], [j]
    trajectory = Trajectory(1)
    if Ruckig(1).calculate(inp, trajectory) not in (Result.Working, Result.Finished):
        raise RuntimeError("ruckig failed")
    return float(trajectory.duration)


def ruckig_comparison(period_s: float) -> str:
    try:
        import ruckig  # noqa: F401
    except ImportError as err:
        return f"ruckig is not installed ({err}); `pip install ruckig` to run this comparison."
    v, a, j = 200.0, 2500.0, JERK_MM_S3
    rows = ["| line mm | lookahead s | ruckig s | ratio | target <= 1.01 | max accel | max jerk |", "|---|---|---|---|---|---|---|"]
    for length in (2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 500.0):
        program = line_program(length)
        limits = PlanLimits(period_s=period_s, chord_error_mm=0.01, max_accel_mm_s2=a, max_jerk_mm_s3=j, feed_mm_s=v)
        ours = plan_lookahead(program, limits)
        m = measure(ours, program)
        theirs = ruckig_duration(length, v, a, j)
        ratio = m.duration_s / theirs
        rows.append(f"| {length:g} | {m.duration_s:.4f} | {theirs:.4f} | {ratio:.4f} | {'met' if ratio <= 1.01 else 'NOT met'} "
                    f"| {m.max_accel_mm_s2:.1f} | {m.max_jerk_mm_s3:.0f} |")
    return (f"Straight line, v <= {v:g} mm/s, a <= {a:g} mm/s^2, j <= {j:g} mm/s^3, T = {period_s * 1000:g} ms "
            "(our motion time includes the stretch to a whole number of cycles, < T).\n\n" + "\n".join(rows))


# ---- throughput -------------------------------------------------------------------------------------
THROUGHPUT_SCRIPT = r"""
import json, resource, statistics, sys, time
sys.path.insert(0, sys.argv[4])  # the version measured: only its nurbsmotion is imported
if sys.argv[2] == "keep":
    from nurbsmotion.runtime import keep_freed_memory
    keep_freed_memory()
from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.planning import PlanLimits
from nurbsmotion.planning.lookahead import PlanStream, plan_lookahead
from nurbsmotion.program import Block, BlockKind, Program, SourceRef
points, weights, knots = json.loads(sys.argv[5])
chunk_cycles = int(sys.argv[6])  # 0: the whole plan (plan_lookahead); else PlanStream's chunks, not kept
jerk = None if sys.argv[3] == "none" else float(sys.argv[3])
limits = PlanLimits(period_s=0.001, chord_error_mm={chord!r}, max_accel_mm_s2={accel!r}, feed_mm_s={feed!r},
                    max_jerk_mm_s3=jerk)
best, count, faults, times, cpu = float("inf"), 0, 0, [], []
for _ in range(int(sys.argv[1])):
    curve = NurbsCurve.create(2, points, weights, knots)  # a fresh curve: its tables are built inside the timing
    program = Program("wang_table1", (Block(BlockKind.NURBS, curve, {feed!r}, SourceRef("wang_table1", 1)),),
                      curve.start_point)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    started, started_cpu = time.perf_counter(), time.process_time()
    if chunk_cycles:
        count = sum(len(chunk) for chunk in PlanStream(program, limits, chunk_cycles))
    else:
        count = len(plan_lookahead(program, limits))
    elapsed = time.perf_counter() - started
    cpu.append(time.process_time() - started_cpu)
    times.append(elapsed)
    if elapsed < best:
        best, faults = elapsed, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
print(json.dumps({{"best_s": best, "median_s": statistics.median(times), "count": count, "faults": faults,
                  "cpu_median_s": statistics.median(cpu)}}))
"""


CHUNK_CYCLES = 2000  # PlanStream's default chunk, what streamed daemon jobs use


def throughput(repeat: int, previous_src: str | None = None, processes: int = 3) -> str:
    """Each case in ``processes`` fresh processes: with glibc's default allocator (a bare
    library call), and with runtime.keep_freed_memory() as the nurbsmotion command sets it;
    the previous version (another checkout's src) the same way when given, interleaved so both
    see the same load. With J also chunked planning (PlanStream, CHUNK_CYCLES) in the
    nurbsmotion process. Reported: the best plan of all processes, the median of the
    processes' median wall times, and the median of their median CPU times (process_time:
    what the plan costs when the other agents on this shared host take the cores away)."""
    rows = ["| Wang Table 1, T = 1 ms | version | process | set-points | best planning s | median planning s "
            "| median CPU ms / plan | page faults (best) | set-points / s (best) | set-points / s (median) "
            "| set-points / CPU s (median) | target |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    script = THROUGHPUT_SCRIPT.format(chord=WANG_LIMITS.chord_error_mm, accel=WANG_LIMITS.max_accel_mm_s2,
                                      feed=WANG_LIMITS.feed_mm_s)
    curve = json.dumps([np.asarray(WANG_POINTS).tolist(), list(WANG_WEIGHTS), list(WANG_KNOTS)])
    versions = [("this", str(ROOT / "src"))] + ([("previous", previous_src)] if previous_src else [])
    chunked = f"nurbsmotion command, PlanStream chunks of {CHUNK_CYCLES}"
    cases = [(label, process, mode, jerk, 0) for label, jerk in (("no jerk limit", "none"), (f"J = {JERK_MM_S3:g}", str(JERK_MM_S3)))
             for process, mode in (("library call (glibc default allocator)", "default"),
                                   ("nurbsmotion command (keep_freed_memory)", "keep"))]
    cases.append((f"J = {JERK_MM_S3:g}", chunked, "keep", str(JERK_MM_S3), CHUNK_CYCLES))
    loads = [os.getloadavg()[0]]
    for label, process, mode, jerk, chunk_cycles in cases:
        runs: dict[str, list[dict]] = {version: [] for version, _ in versions}
        for _ in range(processes):
            for version, src in versions:
                out = subprocess.run([sys.executable, "-c", script, str(repeat), mode, jerk, src, curve, str(chunk_cycles)],
                                     capture_output=True, text=True, check=True)
                runs[version].append(json.loads(out.stdout.strip().splitlines()[-1]))
        loads.append(os.getloadavg()[0])
        for version, _ in versions:
            r = runs[version]
            best = min(r, key=lambda run: run["best_s"])
            median_s = float(np.median([run["median_s"] for run in r]))
            cpu_s = float(np.median([run["cpu_median_s"] for run in r]))
            count = best["count"]
            rate = count / best["best_s"]
            rows.append(f"| {label} | {version} | {process} | {count} | {best['best_s']:.4f} | {median_s:.4f} | "
                        f"{cpu_s * 1000:.2f} | {best['faults']} | {rate:,.0f} | {count / median_s:,.0f} | "
                        f"{count / cpu_s:,.0f} | >= 1,000,000 ({'met' if rate >= 1e6 else 'NOT met'}) |")
    load = os.getloadavg()
    return (f"{repeat} plans per process, {processes} fresh processes per case and version (interleaved); best = "
            f"the fastest plan of all, medians = the median over the processes of each process's median; page "
            f"faults = minor faults during the best run. The machine was shared with other agents' work (1-minute "
            f"load average {min(loads):.1f}-{max(loads):.1f} during the run, {load[0]:.1f} / {load[1]:.1f} / "
            f"{load[2]:.1f} over 1 / 5 / 15 min at the end, on {os.cpu_count()} cores): wall-clock rates are lower "
            "bounds of a quiet machine's; CPU time is less sensitive to the load."
            + ("" if not previous_src else f" \"previous\": {previous_src} (the planner before this change).")
            + "\n\n" + "\n".join(rows))


# ---- one hour -------------------------------------------------------------------------------------
HOUR_SCRIPT = r"""
import json, resource, sys, time
sys.path.insert(0, {src!r}); sys.path.insert(0, {root!r})
from benchmarks.bench_lookahead import racetrack_program
from nurbsmotion.planning import PlanLimits
from nurbsmotion.planning.lookahead import plan_lookahead_chunks
laps = int(sys.argv[1])
program = racetrack_program(laps)
limits = PlanLimits(period_s=0.001, chord_error_mm=0.01, max_accel_mm_s2=2500.0, max_jerk_mm_s3=50000.0, feed_mm_s=200.0)
started = time.perf_counter()
count = 0
chunks = 0
for chunk in plan_lookahead_chunks(program, limits, chunk_cycles=2000):
    count += len(chunk)
    chunks += 1
elapsed = time.perf_counter() - started
print(json.dumps(dict(blocks=len(program.blocks), setpoints=count, chunks=chunks, seconds=elapsed,
                      motion_s=(count - 1) * limits.period_s, max_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)))
"""


def racetrack_program(laps: int) -> Program:
    """Laps of a 300 x 100 mm racetrack (lines and R 50 half circles, tangent joins)."""
    blocks = []
    source = SourceRef("racetrack", 1)
    for _ in range(laps):
        blocks.append(Block(BlockKind.LINE, line_curve((0, 0, 0), (300, 0, 0)), None, source))
        blocks.append(Block(BlockKind.ARC, arc_curve((300, 50, 0), (300, 0, 0), np.pi), None, source))
        blocks.append(Block(BlockKind.LINE, line_curve((300, 100, 0), (0, 100, 0)), None, source))
        blocks.append(Block(BlockKind.ARC, arc_curve((0, 50, 0), (0, 100, 0), np.pi), None, source))
    return Program("racetrack", tuple(blocks), np.zeros(3))


def one_hour(minutes: float) -> str:
    def run(laps: int) -> dict:
        script = HOUR_SCRIPT.format(src=str(ROOT / "src"), root=str(ROOT))
        out = subprocess.run([sys.executable, "-c", script, str(laps)], capture_output=True, text=True, check=True)
        return json.loads(out.stdout.strip().splitlines()[-1])

    short, longer = run(4), run(8)
    per_lap = (longer["motion_s"] - short["motion_s"]) / 4.0  # without the start and the stop
    laps = max(8, int(np.ceil(minutes * 60.0 / per_lap)))
    result = run(laps)
    return f"""
Racetrack (300 x 100 mm, R 50 half circles, tangent joins) x {laps} laps = {result['blocks']} blocks,
T = 1 ms, J = {JERK_MM_S3:g} mm/s^3, streamed through plan_lookahead_chunks(chunk_cycles=2000) without
keeping the set-points (a separate process; peak resident memory from getrusage):

| motion time | set-points | chunks | planning s | set-points / s | peak memory MB | target |
|---|---|---|---|---|---|---|
| {result['motion_s'] / 60:.1f} min | {result['setpoints']:,} | {result['chunks']} | {result['seconds']:.1f} | {result['setpoints'] / result['seconds']:,.0f} | {result['max_rss_mb']:.0f} | < 500 MB ({'met' if result['max_rss_mb'] < 500 else 'NOT met'}) |
"""



def summary(compared: str, toppra_text: str, ruckig_text: str) -> str:
    """The section's short table: lookahead's own rows of ``compared``, toppra's verdict, ruckig's table."""
    lines = compared.splitlines()
    ours = lines[:2] + [line for line in lines[2:] if "| lookahead" in line]
    verdict = [line for line in toppra_text.splitlines() if line.startswith("lookahead / toppra")]
    ratios = [float(line.split("|")[4]) for line in ruckig_text.splitlines() if line.startswith("| ") and
              line.split("|")[1].strip().isdigit()]
    ruckig = (f"at most {max(ratios):.4f}x ruckig's time on lines of 2-500 mm" if ratios
              else ruckig_text.splitlines()[0])
    return ("Wang's limits (T = 4 ms, chord error 10 um, a = 2500 mm/s^2, F = 200 mm/s); the papers' "
            "interpolators in the full result.\n\n" + "\n".join(ours) + "\n\nAgainst toppra (per-axis limits, "
            "no J): " + (verdict[0] if verdict else toppra_text.splitlines()[0]) + "\n\nJerk-limited straight "
            "line against ruckig: " + ruckig + ".")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--hour-minutes", type=float, default=60.0)
    parser.add_argument("--previous-src", metavar="DIR", help="src/ of a checkout of the previous version: its throughput too")
    parser.add_argument("--processes", type=int, default=3, help="fresh processes per throughput case and version")
    parser.add_argument("--throughput-only", action="store_true", help="print the throughput table only (docs unchanged)")
    args = parser.parse_args()
    if args.throughput_only:
        print(throughput(args.repeat, args.previous_src, args.processes))
        return
    programs = {"Wang Table 1": read_program(ROOT / "examples" / "wang_table1.nc"),
                "sharp corners": read_program(ROOT / "examples" / "sharp_corners.yaml"),
                "mixed.nc": read_program(ROOT / "examples" / "mixed.nc")}
    compared, toppra_text, ruckig_text = comparison(programs), toppra_comparison(0.001), ruckig_comparison(0.001)
    rates = throughput(args.repeat, args.previous_src, args.processes)
    body = f"""
### Against the papers' interpolators

Wang's limits (T = 4 ms, chord error 10 um, a = 2500 mm/s^2, F = 200 mm/s) for all; the papers'
methods do not limit jerk, so lookahead is shown without and with J = {JERK_MM_S3:g} mm/s^3. Figures are
measured on the set-points by planning.measure (its fluctuation uses the chord |p_i - p_i-1|, which
is shorter than the arc by ~ dL^3 kappa^2 / 24, and at a corner passed moving cuts the corner);
"arc" is lookahead's own guarantee: arc length between set-points vs planned step.

{compared}

### Time-optimality against toppra

{toppra_text}

### Jerk-limited straight line against ruckig

{ruckig_text}

### Throughput

{rates}
"""
    if args.hour_minutes > 0:
        body += "\n### A one-hour program in bounded memory\n" + one_hour(args.hour_minutes)
    write_section("lookahead", "Look-ahead planner", summary(compared, toppra_text, ruckig_text),
                  "python benchmarks/bench_lookahead.py", detail=body)


if __name__ == "__main__":
    main()
