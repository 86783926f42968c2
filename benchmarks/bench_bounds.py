"""Lower bounds on the motion time of the short-segment CAM programs with a jerk limit
(issue 24): how close the look-ahead's plan is to what the limits allow on its own path, and
whether LinuxCNC's time (no jerk limit at all) is reachable with J = 50000 mm/s^3.

Along the planned path (planned_pieces: smoothed, blended; sampled every 0.01 mm) with
T = 1 ms, A = 2500 mm/s^2, J = 50000 mm/s^3, feeds capped at 200 mm/s, tolerance 0.01 mm:
- feeds alone: sum of length / F;
- caps: every point at its largest speed, min(F, sqrt(A / kappa), (J / (|dc/ds| + kappa^2))^(1/3))
  (the path's own normal acceleration and its jerk at constant speed, x''' = x_sss v^3 with
  |x_sss| >= |dc/ds| and kappa^2; full J, no planning margin), no time to change speed;
- caps + A: the same with the tangential acceleration limited to A (a forward and a backward
  scan in v^2, the normal acceleration not counted against it) and rest at the plan's own
  stops: still a lower bound (no tangential jerk);
- the plan's time and its speed dips (local minima over 0.1 s below 0.6 of the block's feed):
  with a jerk limit each dip's change of acceleration takes about A / J more;
- the plan's stops, each by its reason (the junctions of the planned path where a run ends):
  `program` (G61, dwell, M0/M6), `rapid/feed` (a rapid meets a feed move: its blend is measured
  against the rapid's speed, and LinuxCNC stops there too, tp.c handleModeChange), `reversal`
  (deflection above blend.SHARP_LIMIT_DEG), `crawl` (a corner whose G2 blend within the
  tolerance passes below SHARP_PASS_SHARE of the faster feed: its largest speed in brackets,
  the median over those corners), `other`;
- forced: caps + A with rest only at `program` and `reversal` stops and every other stop
  passed at its blend's speed (`rapid/feed`, `crawl`: what the physics allows within the
  tolerance, not our rule), and each straight rest-to-rest run of one feed (rapids, plunges)
  at its 1-D jerk-limited time (S-curve at F, A, J: exact on a line, from rest: its ends
  passed at the blend's few mm/s would save a few ms each): a lower bound with J to that.

Run: python benchmarks/bench_bounds.py [--write]
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))

from benchmarks._report import write_section  # noqa: E402
from benchmarks.bench_blend import LINUXCNC_S, limits, programs  # noqa: E402
from nurbsmotion.geometry import corner_blend as cb  # noqa: E402
from nurbsmotion.planning.lookahead import blend, plan_lookahead, planned_pieces  # noqa: E402
from nurbsmotion.planning.lookahead.api import path_pieces  # noqa: E402
from nurbsmotion.planning.lookahead.path import BlockPiece  # noqa: E402
from nurbsmotion.planning.lookahead.planner import settings_for  # noqa: E402
from nurbsmotion.planning.lookahead.runs import ProgramStops, end_tangents, split_runs  # noqa: E402
from nurbsmotion.planning.lookahead.setup import max_program_feed  # noqa: E402
from nurbsmotion.program import BlockKind  # noqa: E402
from nurbsmotion.program import Program  # noqa: E402

JERK = 50000.0
ACCEL = 2500.0
STEP_MM = 0.01


def piece_length(piece: BlockPiece) -> float:
    return float(piece.curve.arc_length(piece.u_end) - piece.curve.arc_length(piece.u_start))


def jerk_limited_time(distance_mm: float, feed_mm_s: float) -> float:
    """Fastest rest-to-rest move of ``distance_mm`` along a line under F, A and J (a symmetric
    S-curve: reaching v takes v / A + A / J over v (v / A + A / J) / 2, or 2 sqrt(v / J) over
    v sqrt(v / J) when v < A^2 / J)."""
    def ramp(v: float) -> tuple[float, float]:
        t = v / ACCEL + ACCEL / JERK if v >= ACCEL**2 / JERK else 2.0 * np.sqrt(v / JERK)
        return t, 0.5 * v * t

    t, d = ramp(feed_mm_s)
    if 2.0 * d <= distance_mm:
        return 2.0 * t + (distance_mm - 2.0 * d) / feed_mm_s
    lo, hi = 0.0, feed_mm_s
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if 2.0 * ramp(mid)[1] <= distance_mm else (lo, mid)
    return 2.0 * ramp(lo)[0]


def is_straight(pieces: tuple[BlockPiece, ...]) -> bool:
    """One line, or lines in one direction."""
    if not all(p.curve.degree == 1 and len(p.curve.control_points) == 2 for p in pieces):
        return False
    first = end_tangents(pieces[0])[0]
    return all(float(np.dot(end_tangents(p)[0], first)) > 1.0 - 1e-9 for p in pieces)


def stop_reasons(program: Program) -> tuple[list[tuple[float, str, float]], list[tuple[float, float, float]]]:
    """([(s of the stop, reason, blend speed or 0)], [(s from, s to, jerk-limited time) of each
    straight rest-to-rest run]) along the planned path (module docstring)."""
    lim = limits(JERK, 0.01)
    stops = ProgramStops.of(program, lim)
    pieces = path_pieces(program, lim, stops)
    settings = settings_for(lim, max_program_feed(program, lim), 2000)
    runs = split_runs(pieces, lim, settings.min_pass_mm_s, stops)
    out, straight, s0 = [], [], 0.0
    for k, run in enumerate(runs):
        length = sum(piece_length(p) for p in run.pieces)
        feeds = {p.feed_mm_s for p in run.pieces}
        if is_straight(run.pieces) and len(feeds) == 1:  # a rapid into a collinear plunge: caps + A only
            straight.append((s0, s0 + length, jerk_limited_time(length, feeds.pop())))
        s0 += length
        if k + 1 < len(runs):
            out.append((s0, *stop_reason(run.pieces[-1], runs[k + 1].pieces[0], program, lim, stops)))
    return out, straight


def stop_reason(a: BlockPiece, b: BlockPiece, program: Program, lim, stops: ProgramStops) -> tuple[str, float]:
    """Why the planner stops between pieces a and b, and the speed of their blend within the
    tolerance where one exists (else 0)."""
    if a.last_block in stops.stop_after or stops.dwell_between(a.last_block, b.block) > 0:
        return "program", 0.0
    t_in, t_out = end_tangents(a)[1], end_tangents(b)[0]
    deflection = np.degrees(np.arccos(np.clip(float(np.dot(t_in, t_out)), -1.0, 1.0)))
    if deflection > blend.SHARP_LIMIT_DEG:
        return "reversal", 0.0
    a, b = (replace(p, u_start=p.curve.u_min, u_end=p.curve.u_max) if blend.is_line(p.curve) else p for p in (a, b))
    shapes, known = blend.piece_shapes([a, b])  # lines whole, as blend_pieces saw them before trimming
    speed = 0.0
    if known.all():
        tolerance = blend.corner_tolerances([a, b], lim, stops)
        first, second = shapes.take(np.array([0])), shapes.take(np.array([1]))
        d = cb.trim_distances(first, second, tolerance)
        points = cb.blend_points(first, second, d)
        if d[0] > 0 and cb.monotone(points)[0]:
            speed = float(blend.pass_speed_mm_s(points, lim)[0])
    kinds = {program.blocks[a.last_block].kind == BlockKind.RAPID, program.blocks[b.block].kind == BlockKind.RAPID}
    if len(kinds) == 2:
        return "rapid/feed", speed
    return ("crawl" if speed > 0 else "other"), speed


def forced_bound(s: np.ndarray, cap: np.ndarray, reasons: list[tuple[float, str, float]],
                 straight: list[tuple[float, float, float]]) -> float:
    """caps + A resting only where the program or a reversal forces it, every other stop at its
    blend's speed, and the straight rest-to-rest runs at their jerk-limited time."""
    capped = cap.copy()
    for s_stop, reason, speed in reasons:
        i = min(int(np.searchsorted(s, s_stop)), len(s) - 1)
        capped[i] = 0.0 if reason in ("program", "reversal") else min(capped[i], speed)
    capped[0], capped[-1] = 0.0, 0.0
    v = with_accel(s, capped)
    mean = np.maximum(0.5 * (v[1:] + v[:-1]), 1e-9)
    dt = np.diff(s) / mean
    total = float(np.sum(dt))
    for s_from, s_to, jerk_s in straight:
        inside = (s[:-1] >= s_from - 1e-9) & (s[1:] <= s_to + 1e-9)
        total += max(jerk_s - float(np.sum(dt[inside])), 0.0)
    return total


def reason_counts(reasons: list[tuple[float, str, float]]) -> str:
    counted = Counter(r for _, r, _ in reasons)
    parts = []
    for name in ("program", "rapid/feed", "reversal", "crawl", "other"):
        if counted[name]:
            speeds = [v for _, r, v in reasons if r == name and v > 0]
            parts.append(f"{name} {counted[name]}" + (f" ({np.median(speeds):.1f} mm/s)" if speeds else ""))
    return ", ".join(parts)


def caps(program: Program) -> tuple[np.ndarray, np.ndarray, float]:
    """(s, speed cap at s, feeds-alone time) along the planned path."""
    s_all, cap_all, feeds_s, s0 = [], [], 0.0, 0.0
    for piece in planned_pieces(program, limits(JERK, 0.01)):
        curve = piece.curve
        length = float(curve.arc_length(piece.u_end) - curve.arc_length(piece.u_start))
        u = np.linspace(piece.u_start, piece.u_end, max(int(length / STEP_MM), 4))
        x, d1, d2 = (np.pad(v, ((0, 0), (0, 3 - v.shape[1])))[:, :3] for v in curve.derivatives(u, 2))
        speed = np.maximum(np.linalg.norm(d1, axis=1), 1e-300)
        t = d1 / speed[:, None]
        c = (d2 - np.einsum("ij,ij->i", d2, t)[:, None] * t) / (speed**2)[:, None]
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(x, axis=0), axis=1))])
        kappa = np.linalg.norm(c, axis=1)
        rate = np.concatenate([np.linalg.norm(np.diff(c, axis=0), axis=1) / np.maximum(np.diff(s), 1e-12), [0.0]])
        cap = np.minimum(piece.feed_mm_s, np.minimum(np.sqrt(ACCEL / np.maximum(kappa, 1e-12)),
                                                     np.cbrt(JERK / np.maximum(rate + kappa**2, 1e-12))))
        s_all.append(s0 + s)
        cap_all.append(cap)
        feeds_s += length / piece.feed_mm_s
        s0 += float(s[-1])
    return np.concatenate(s_all), np.concatenate(cap_all), feeds_s


def time_s(s: np.ndarray, v: np.ndarray) -> float:
    """Time along s at speeds v (constant acceleration between samples: ds over the mean speed)."""
    mean = np.maximum(0.5 * (v[1:] + v[:-1]), 1e-9)
    return float(np.sum(np.diff(s) / mean))


def with_accel(s: np.ndarray, cap: np.ndarray) -> np.ndarray:
    """Largest speeds under the caps with |dv/dt| <= A (v^2 changes by at most 2 A ds)."""
    x = cap**2
    ds = np.diff(s)
    for i in range(1, len(x)):
        x[i] = min(x[i], x[i - 1] + 2.0 * ACCEL * ds[i - 1])
    for i in range(len(x) - 2, -1, -1):
        x[i] = min(x[i], x[i + 1] + 2.0 * ACCEL * ds[i])
    return np.sqrt(x)


def row(name: str, program: Program) -> str:
    trajectory = plan_lookahead(program, limits(JERK, 0.01))
    s, cap, feeds_s = caps(program)
    step = np.linalg.norm(np.diff(trajectory.position_mm, axis=0), axis=1)
    travelled = np.concatenate([[0.0], np.cumsum(step)])
    rest = travelled[np.flatnonzero(step == 0.0) + 1] * s[-1] / max(travelled[-1], 1e-300)
    stops = np.unique(np.clip(np.searchsorted(s, rest), 0, len(s) - 1))
    stopped = cap.copy()
    stopped[stops], stopped[0], stopped[-1] = 0.0, 0.0, 0.0
    accel_s = time_s(s, with_accel(s, stopped))
    v = trajectory.feed_mm_s
    feed = np.array([limits(JERK, 0.01).feed_for(b.feed_mm_s) for b in program.blocks])[trajectory.block]
    window = np.pad(v, 50, mode="edge")
    low = (v == sliding_window_view(window, 101).min(axis=1)) & (v < 0.6 * feed)
    dips = int(np.count_nonzero(np.diff(low.astype(int)) == 1))
    linuxcnc = LINUXCNC_S[name]
    plan_s = trajectory.duration_s
    reasons, straight = stop_reasons(program)
    forced_s = forced_bound(s, cap, reasons, straight)
    line = (f"| {name} | {linuxcnc:.2f} s | {feeds_s:.2f} s | {time_s(s, cap):.2f} s ({time_s(s, cap) / linuxcnc:.2f}x) | "
            f"{accel_s:.2f} s ({accel_s / linuxcnc:.2f}x) | {len(stops)}: {reason_counts(reasons)} | "
            f"{forced_s:.2f} s ({forced_s / linuxcnc:.2f}x) | {plan_s:.2f} s ({plan_s / linuxcnc:.2f}x) | "
            f"{dips} | {dips * ACCEL / JERK:.1f} s |")
    print(line, flush=True)
    return line


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--write", action="store_true", help="write the section of docs/benchmarks.md")
    args = parser.parse_args()
    header = ("| program | LinuxCNC 2.9 (no J) | feeds alone | caps | caps + A, the plan's stops | stops: why | "
              "forced (lower bound with J) | our plan, J = 50000 | speed dips | dips x A/J |\n"
              "|---|---|---|---|---|---|---|---|---|---|")
    print(header)
    rows = [row(name, program) for name, program in programs().items()]
    if args.write:
        body = (__doc__.split("\n\n")[1] + "\n\n" + header + "\n" + "\n".join(rows))
        write_section("bounds", "Jerk-limited lower bounds (short-segment CAM programs)", body,
                      "python benchmarks/bench_bounds.py --write")


if __name__ == "__main__":
    main()
