"""Corner blending and short-segment smoothing (issue 24): motion time, planning time and
speed, and the largest deviation from the programmed path of the look-ahead plan on the
short-segment CAM programs of the LinuxCNC race, with and without the jerk limit: `corners`
(path tolerance 0: every corner a junction, as before blending), `blended` (tolerance 0.01 mm,
smoothing off) and `smoothed` (tolerance 0.01 mm, smoothing on: the default).

Limits as in the race (docs/../shared reference linuxcnc-peer.md): T = 1 ms, resultant
A = 2500 mm/s^2, every feed capped at 200 mm/s (the program's F above it, and rapids),
chord error 0.01 mm, junction deviation 0.01 mm; J = 50000 mm/s^3 (the daemon's default) or
none. grbl's HSM_test.nc and braid_cut2d.nc (F7000, as tests/planning/lookahead/
test_no_give_ups.braid_program reads it), CAMotics' vcarve.ngc as the race reads it
(bench_vs_linuxcnc.vcarve_fix, its G64 at 0.01 mm). The deviation is the planner's own verified
figure (verified_max_path_deviation_mm: every set-point on a blend or a smoothed piece against
the program's lines it stands for).

Also writes a picture of the sharpest blended corner of the braid against its polyline
(docs/img/corner_blend.png) with --plot (--only-plot: nothing else).

Run: python benchmarks/bench_blend.py [--write] [--plot] [--no-baseline]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))

from benchmarks._report import write_section  # noqa: E402
from nurbsmotion.planning import PlanLimits  # noqa: E402
from nurbsmotion.planning.lookahead import plan_lookahead, planned_pieces  # noqa: E402
from nurbsmotion.program import Program, read_program  # noqa: E402
from nurbsmotion.program.model import with_feeds_capped  # noqa: E402

FEED_CAP_MM_S = 200.0
LINUXCNC_S = {"HSM_test": 20.39, "braid F7000": 16.70, "V-carve": 30.11}  # /work/shared/reference/linuxcnc-peer.md, 2026-11-28
HSM = ROOT / "tests" / "data" / "gcode" / "grbl_HSM_test.nc"
VCARVE = ROOT / "tests" / "data" / "gcode" / "camotics_vcarve.ngc"
IMG = ROOT / "docs" / "img" / "corner_blend.png"


def capped(program: Program) -> Program:
    """Every programmed feed at most FEED_CAP_MM_S (LinuxCNC's MAX_LINEAR_VELOCITY)."""
    return with_feeds_capped(program, FEED_CAP_MM_S)


def programs() -> dict[str, Program]:
    from benchmarks.bench_vs_linuxcnc import vcarve_fix
    from benchmarks.linuxcnc_peer import with_tolerance
    from nurbsmotion.program import parse_gcode
    from tests.planning.lookahead.test_no_give_ups import braid_program
    vcarve = with_tolerance(vcarve_fix(VCARVE.read_text()), 0.01)
    return {"HSM_test": capped(read_program(HSM)), "braid F7000": capped(braid_program()),
            "V-carve": capped(parse_gcode(vcarve, VCARVE.name))}


MODES = {"corners": (0.0, False), "blended": (0.01, False), "smoothed": (0.01, True)}  # tolerance, smoothing


def limits(jerk: float | None, tolerance_mm: float, smoothing: bool = True) -> PlanLimits:
    return PlanLimits(period_s=0.001, chord_error_mm=0.01, max_accel_mm_s2=2500.0, max_jerk_mm_s3=jerk,
                      default_feed_mm_s=FEED_CAP_MM_S, rapid_feed_mm_s=FEED_CAP_MM_S, junction_deviation_mm=0.01,
                      path_tolerance_mm=tolerance_mm, smoothing=smoothing)


def row(name: str, program: Program, jerk: float | None, mode: str) -> str:
    started = time.perf_counter()
    trajectory = plan_lookahead(program, limits(jerk, *MODES[mode]))
    wall = time.perf_counter() - started
    notes = trajectory.notes
    motion = trajectory.duration_s
    linuxcnc = LINUXCNC_S[name]
    line = (f"| {name} | {'none' if jerk is None else f'{jerk:g}'} | {mode} | "
            f"{motion:.2f} s | {motion / linuxcnc:.2f}x | {wall:.1f} s | {len(trajectory) / wall:,.0f} | {notes['stops']} | "
            f"{float(notes.get('verified_max_path_deviation_mm', 0.0)) * 1000:.2f} um | "
            f"{float(notes['verified_max_accel_mm_s2']):.0f} | {float(notes['verified_max_jerk_mm_s3']):.3g} |")
    print(line, flush=True)
    return line


def plot_corner(path: Path) -> None:
    """The sharpest blended corner of the braid program against its polyline."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    program = programs()["braid F7000"]
    pieces = planned_pieces(program, limits(50000.0, 0.01, smoothing=False))
    blends = [i for i, p in enumerate(pieces) if p.corners is not None]

    def sharpness(i: int) -> float:
        corners = pieces[i].corners
        assert corners is not None
        k = pieces[i].corner
        t_in = corners.incoming.direction[k]
        t_out = corners.outgoing.direction[k]
        return float(np.dot(t_in, t_out))

    i = min(blends, key=sharpness)  # the sharpest corner blended
    before, blend, after = pieces[i - 1], pieces[i], pieces[i + 1]
    corners = blend.corners
    assert corners is not None
    k = blend.corner
    corner = corners.incoming.start[k] + corners.incoming.length_mm[k] * corners.incoming.direction[k]
    fig, ax = plt.subplots(figsize=(6, 6))
    for piece in (before, after):
        p = piece.curve.points(np.linspace(piece.u_start, piece.u_end, 100))
        ax.plot(p[:, 0], p[:, 1], "C0-", lw=2)
    reach = 1.6 * float(np.max(np.linalg.norm(blend.curve.points(np.array([0.0, 1.0]))[:, :2] - corner[:2], axis=1)))
    a = corner - reach * corners.incoming.direction[k]
    b = corner + reach * corners.outgoing.direction[k]
    ax.plot([a[0], corner[0], b[0]], [a[1], corner[1], b[1]], "k--", lw=1, label="programmed polyline")
    p = blend.curve.points(np.linspace(0.0, 1.0, 200))
    turn = np.degrees(np.arccos(np.clip(np.dot(corners.incoming.direction[k], corners.outgoing.direction[k]), -1, 1)))
    ax.plot(p[:, 0], p[:, 1], "C3-", lw=2, label=f"quintic G2 blend, tolerance 0.01 mm ({turn:.0f} deg corner)")
    ax.plot(*corner[:2], "ko")
    ax.set_aspect("equal")
    ax.legend(loc="best")
    ax.set_title(f"braid_cut2d block {pieces[i].block + 1}: the sharpest blended corner")
    ax.set_xlabel("X (mm)")
    ax.set_ylabel("Y (mm)")
    ax.set_xlim(corner[0] - reach, corner[0] + reach)
    ax.set_ylim(corner[1] - reach, corner[1] + reach)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    print(f"wrote {path}")


SWEEP_JERKS = (1e4, 5e4, 1e5, 1e6, 1e8, 1e12, None)  # issue 24: the time falls monotonically towards no limit


def sweep(write: bool) -> None:
    """Each program's smoothed plan at every jerk limit of SWEEP_JERKS, and whether its motion
    time falls monotonically as J grows (to the plan without a limit)."""
    header = ("| program | J (mm/s^3) | corners | motion | vs LinuxCNC 2.9 | planning (wall) | set-points/s | stops "
              "| max deviation | max accel | max jerk |\n|---|---|---|---|---|---|---|---|---|---|---|")
    print(header)
    rows, verdicts = [], []
    for name, program in programs().items():
        times = []
        for jerk in SWEEP_JERKS:
            rows.append(row(name, program, jerk, "smoothed"))
            times.append(float(rows[-1].split("|")[4].split()[0]))
        falls = all(b <= a + 0.005 for a, b in zip(times, times[1:]))
        verdicts.append(f"{name}: {' > '.join(f'{t:.2f}' for t in times)} s, "
                        f"{'monotone' if falls else 'NOT monotone'}")
        print(verdicts[-1], flush=True)
    if write:
        how = ("Smoothed and blended within 0.01 mm (the default), T = 1 ms, A = 2500 mm/s^2, feeds capped at "
               "200 mm/s; J from 1e4 to none (the plan's time must fall monotonically towards the unlimited "
               "plan, issue 24; equal within 5 ms counts).")
        verdict_list = "\n".join(f"- {v}" for v in verdicts)
        body = f"{how}\n\n" + header + "\n" + "\n".join(rows) + "\n\n" + verdict_list
        write_section("jerk_sweep", "Jerk limit sweep (short-segment CAM programs)",
                      f"Motion time at J = {', '.join(f'{j:g}' for j in SWEEP_JERKS if j)}, none:\n\n{verdict_list}",
                      "python benchmarks/bench_blend.py --sweep --write", detail=body)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--write", action="store_true", help="write the section of docs/benchmarks.md")
    parser.add_argument("--plot", action="store_true", help=f"write {IMG.relative_to(ROOT)}")
    parser.add_argument("--no-baseline", action="store_true", help="only the smoothed plans (the default settings)")
    parser.add_argument("--only-plot", action="store_true", help="only the picture")
    parser.add_argument("--sweep", action="store_true", help="the smoothed plans at SWEEP_JERKS (section jerk_sweep)")
    args = parser.parse_args()
    if args.sweep:
        sweep(args.write)
        return
    if args.plot or args.only_plot:
        plot_corner(IMG)
    if args.only_plot:
        return
    header = ("| program | J (mm/s^3) | corners | motion | vs LinuxCNC 2.9 | planning (wall) | set-points/s | stops "
              "| max deviation | max accel | max jerk |\n|---|---|---|---|---|---|---|---|---|---|---|")
    print(header)
    rows = []
    load_before = os.getloadavg()[0]
    for name, program in programs().items():
        for jerk in (50000.0, None):
            for mode in (("smoothed",) if args.no_baseline else MODES):
                rows.append(row(name, program, jerk, mode))
    load = f"host load average {load_before:.1f} at the start, {os.getloadavg()[0]:.1f} at the end"
    if args.write:
        body = (f"{load}. T = 1 ms, A = 2500 mm/s^2 resultant, feeds capped at 200 mm/s, chord error 0.01 mm; "
                "`corners`: path tolerance 0 (every corner a junction, as before blending); `blended`: "
                "path tolerance 0.01 mm (G64 P0.01), smoothing off; `smoothed`: the same with short-segment "
                "smoothing (the default). LinuxCNC 2.9's times from the race "
                "(shared reference linuxcnc-peer.md, same limits).\n\n" + header + "\n" + "\n".join(rows))
        write_section("blend", "Corner blending and smoothing", body, "python benchmarks/bench_blend.py --write")


if __name__ == "__main__":
    main()
