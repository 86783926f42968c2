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

With --breakdown: where each plan's time goes against the forced bound, by class of step
(cruise, dip, stop, rapid), beside a tighter lower bound with J at each slow stretch's lowest
point and a feasible profile of the tangential jerk model (BREAKDOWN says what each is).

With --no-jerk: the same kind of bounds without a jerk limit, along the path planned without J
(NO_JERK says what each column is; printed only).

Run: python benchmarks/bench_bounds.py [--breakdown | --no-jerk] [--write]
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
from nurbsmotion.planning.lookahead.speed_limits import floor_log2, min_table  # noqa: E402
from nurbsmotion.program import BlockKind  # noqa: E402
from nurbsmotion.program import Program  # noqa: E402

JERK = 50000.0
FEED_LIMIT_MM_S = 200.0
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


def stop_reasons(program: Program, jerk: float | None = JERK
                 ) -> tuple[list[tuple[float, str, float]], list[tuple[float, float, float]]]:
    """([(s of the stop, reason, blend speed or 0)], [(s from, s to, jerk-limited time) of each
    straight rest-to-rest run; none without a jerk limit: with_accel is exact there]) along the
    planned path (module docstring)."""
    lim = limits(jerk, 0.01)
    stops = ProgramStops.of(program, lim)
    pieces = path_pieces(program, lim, stops)
    settings = settings_for(lim, max_program_feed(program, lim), 2000)
    runs = split_runs(pieces, lim, settings.min_pass_mm_s, stops)
    out, straight, s0 = [], [], 0.0
    for k, run in enumerate(runs):
        length = sum(piece_length(p) for p in run.pieces)
        feeds = {p.feed_mm_s for p in run.pieces}
        if jerk is not None and is_straight(run.pieces) and len(feeds) == 1:  # a rapid into a collinear plunge: caps + A only
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


def forced_speeds(s: np.ndarray, cap: np.ndarray, reasons: list[tuple[float, str, float]]) -> np.ndarray:
    """caps + A resting only where the program or a reversal forces it, every other stop at its
    blend's speed."""
    return with_accel(s, rested(s, cap, reasons, ("program", "reversal")))


def forced_steps(s: np.ndarray, v: np.ndarray, straight: list[tuple[float, float, float]]) -> np.ndarray:
    """Time of each step of s at the forced speeds v, each straight rest-to-rest run's steps
    stretched to its jerk-limited time."""
    mean = np.maximum(0.5 * (v[1:] + v[:-1]), 1e-9)
    dt = np.diff(s) / mean
    for s_from, s_to, jerk_s in straight:
        inside = (s[:-1] >= s_from - 1e-9) & (s[1:] <= s_to + 1e-9)
        accel_s = float(np.sum(dt[inside]))
        if accel_s > 0.0 and jerk_s > accel_s:
            dt[inside] *= jerk_s / accel_s
    return dt


def forced_bound(s: np.ndarray, cap: np.ndarray, reasons: list[tuple[float, str, float]],
                 straight: list[tuple[float, float, float]]) -> float:
    """caps + A resting only where the program or a reversal forces it, every other stop at its
    blend's speed, and the straight rest-to-rest runs at their jerk-limited time."""
    return float(np.sum(forced_steps(s, forced_speeds(s, cap, reasons), straight)))


def reason_counts(reasons: list[tuple[float, str, float]]) -> str:
    counted = Counter(r for _, r, _ in reasons)
    parts = []
    for name in ("program", "rapid/feed", "reversal", "crawl", "other"):
        if counted[name]:
            speeds = [v for _, r, v in reasons if r == name and v > 0]
            parts.append(f"{name} {counted[name]}" + (f" ({np.median(speeds):.1f} mm/s)" if speeds else ""))
    return ", ".join(parts)


def caps(program: Program, jerk: float | None = JERK) -> tuple[np.ndarray, np.ndarray, float]:
    """(s, speed cap at s, feeds-alone time) along the planned path."""
    s, cap, feeds_s, _, _ = caps_and_blocks(program, jerk)
    return s, cap, feeds_s


def caps_and_blocks(program: Program, jerk: float | None = JERK
                    ) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, np.ndarray]:
    """caps with the block of every sample (a blend's: its outgoing block's) and the curvature
    there; without a jerk limit the caps are the feed and sqrt(A / kappa)."""
    s_all, cap_all, block_all, kappa_all, feeds_s, s0 = [], [], [], [], 0.0, 0.0
    for piece in planned_pieces(program, limits(jerk, 0.01)):
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
        cap = np.minimum(piece.feed_mm_s, np.sqrt(ACCEL / np.maximum(kappa, 1e-12)))
        if jerk is not None:
            cap = np.minimum(cap, np.cbrt(jerk / np.maximum(rate + kappa**2, 1e-12)))
        s_all.append(s0 + s)
        kappa_all.append(kappa)
        cap_all.append(cap)
        block_all.append(np.full(len(s), piece.block))
        feeds_s += length / piece.feed_mm_s
        s0 += float(s[-1])
    return (np.concatenate(s_all), np.concatenate(cap_all), feeds_s, np.concatenate(block_all),
            np.concatenate(kappa_all))


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


def plan_rests(trajectory, s: np.ndarray, cap: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(samples of s where the plan rests, the caps with rest there and at both ends): the
    plan's repeated set-points mapped onto s by the distance travelled."""
    step = np.linalg.norm(np.diff(trajectory.position_mm, axis=0), axis=1)
    travelled = np.concatenate([[0.0], np.cumsum(step)])
    rest = travelled[np.flatnonzero(step == 0.0) + 1] * s[-1] / max(travelled[-1], 1e-300)
    stops = np.unique(np.clip(np.searchsorted(s, rest), 0, len(s) - 1))
    stopped = cap.copy()
    stopped[stops], stopped[0], stopped[-1] = 0.0, 0.0, 0.0
    return stops, stopped


def with_resultant_accel(s: np.ndarray, cap: np.ndarray, kappa: np.ndarray) -> np.ndarray:
    """Largest speeds under the caps with a_t^2 + (kappa v^2)^2 <= A^2 (the resultant, as the
    planner limits it): each step of v^2 by at most 2 ds sqrt(A^2 - (kappa_min x)^2), taken at
    the slower end's v^2 and the step's smaller curvature (more room than any profile has, so
    still a lower bound; exact as ds -> 0)."""
    x = cap**2
    ds = np.diff(s)
    k = np.minimum(kappa[1:], kappa[:-1])
    for i in range(1, len(x)):
        room = np.sqrt(max(ACCEL * ACCEL - (k[i - 1] * x[i - 1]) ** 2, 0.0))
        x[i] = min(x[i], x[i - 1] + 2.0 * room * ds[i - 1])
    for i in range(len(x) - 2, -1, -1):
        room = np.sqrt(max(ACCEL * ACCEL - (k[i] * x[i + 1]) ** 2, 0.0))
        x[i] = min(x[i], x[i + 1] + 2.0 * room * ds[i])
    return np.sqrt(x)


def rested(s: np.ndarray, cap: np.ndarray, reasons: list[tuple[float, str, float]], rest: tuple[str, ...]) -> np.ndarray:
    """The caps with rest at the stops of the reasons in ``rest``, every other stop at its blend's
    speed, and rest at both ends."""
    capped = cap.copy()
    for s_stop, reason, speed in reasons:
        i = min(int(np.searchsorted(s, s_stop)), len(s) - 1)
        capped[i] = 0.0 if reason in rest else min(capped[i], speed)
    capped[0], capped[-1] = 0.0, 0.0
    return capped


NO_JERK_HEADER = ("| program | LinuxCNC 2.9 | feeds alone | caps | caps + A (tangent), the plan's stops | stops: why | "
                  "forced, A on the tangent | forced, resultant A | + rest at rapid/feed | our plan, no J |\n"
                  "|---|---|---|---|---|---|---|---|---|---|")


def no_jerk_row(name: str, program: Program) -> str:
    """The bounds without a jerk limit (NO_JERK): along the path planned without J."""
    trajectory = plan_lookahead(program, limits(None, 0.01))
    s, cap, feeds_s, _, kappa = caps_and_blocks(program, None)
    stops, stopped = plan_rests(trajectory, s, cap)
    accel_s = time_s(s, with_accel(s, stopped))
    reasons, _ = stop_reasons(program, None)
    forced = rested(s, cap, reasons, ("program", "reversal"))
    forced_s = time_s(s, with_accel(s, forced))
    resultant_s = time_s(s, with_resultant_accel(s, forced, kappa))
    ruled_s = time_s(s, with_resultant_accel(s, rested(s, cap, reasons, ("program", "reversal", "rapid/feed")), kappa))
    linuxcnc, plan_s = LINUXCNC_S[name], trajectory.duration_s
    cells = [f"{x:.3f} s ({x / linuxcnc:.3f}x)" for x in (time_s(s, cap), accel_s)]
    bounds = [f"{x:.3f} s ({x / linuxcnc:.3f}x)" for x in (forced_s, resultant_s, ruled_s, plan_s)]
    line = (f"| {name} | {linuxcnc:.2f} s | {feeds_s:.3f} s | {cells[0]} | {cells[1]} | {len(stops)}: "
            f"{reason_counts(reasons)} | " + " | ".join(bounds) + " |")
    print(line, flush=True)
    return line


NO_JERK = """Without a jerk limit (--no-jerk), along the path planned without J (its blends sized
and kept by the no-J rules): `caps` min(F, sqrt(A / kappa)) with no time to change speed;
`caps + A` the same with |a_t| <= A and rest at the plan's own stops; `forced, A on the tangent`
rest only at program stops and reversals, every other stop of the plan passed at its blend's
speed (what the tolerance allows); `forced, resultant A` the same with a_t^2 + (kappa v^2)^2 <= A^2
(with_resultant_accel), the tightest lower bound here (continuous time: a 1 ms plan is a few
cycles slower per rest); `+ rest at rapid/feed` also at rest where a rapid meets a feed move (our
rule and LinuxCNC's, tp.c handleModeChange)."""


def row(name: str, program: Program) -> str:
    trajectory = plan_lookahead(program, limits(JERK, 0.01))
    s, cap, feeds_s = caps(program)
    stops, stopped = plan_rests(trajectory, s, cap)
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


JERK_CHOICES = np.array([1.0, 0.5, 0.0, -0.5, -1.0])  # x J: the greedy profile's candidate jerks, best first
CRAWL_MM_S = 0.5  # a forced rest passed at this speed by the greedy profile (it cannot stop and start on a point)


class CapRange:
    """Least cap over the samples of s between two arc lengths (a sparse table of minima)."""

    def __init__(self, s: np.ndarray, cap: np.ndarray) -> None:
        self.s = s
        self.table = min_table(cap, int(np.log2(len(cap))) + 2)

    def between(self, a_mm: np.ndarray, b_mm: np.ndarray) -> np.ndarray:
        lo = np.clip(np.searchsorted(self.s, np.minimum(a_mm, b_mm), side="right") - 1, 0, len(self.s) - 1)
        hi = np.clip(np.searchsorted(self.s, np.maximum(a_mm, b_mm), side="left"), lo, len(self.s) - 1)
        level = floor_log2(hi - lo + 1)
        return np.minimum(self.table[level, lo], self.table[level, hi - (1 << level) + 1])


def step(s: np.ndarray, v: np.ndarray, a: np.ndarray, jerk: np.ndarray, dt: float) -> tuple[np.ndarray, ...]:
    """One cycle of constant jerk (a_t clipped to +-A, v not below 0): (s, v, a) after it."""
    a1 = np.clip(a + jerk * dt, -ACCEL, ACCEL)
    v1 = np.maximum(v + 0.5 * (a + a1) * dt, 0.0)
    return s + 0.5 * (v + v1) * dt, v1, a1


def brakes_within(caps: CapRange, s: np.ndarray, v: np.ndarray, a: np.ndarray, dt: float) -> np.ndarray:
    """Whether the hardest jerk-limited braking to rest from each state (jerk -J to -A, then +J
    so that a_t reaches 0 as v does) stays under the caps: the exact test that some admissible
    continuation exists (it is the lowest v(s) any continuation can have)."""
    ok = np.ones(len(s), dtype=bool)
    for _ in range(int(2.0 * (FEED_LIMIT_MM_S / ACCEL + ACCEL / JERK) / dt) + 2):
        moving = v > 0.0
        if not moving.any():
            break
        release = (a < 0.0) & (a * a / (2.0 * JERK) >= v)
        s1, v1, a1 = step(s, v, a, np.where(release, JERK, -JERK), dt)
        ok &= ~moving | (np.maximum(v, v1) <= caps.between(s, s1) + 1e-9)
        s, v, a = s1, np.where(moving, v1, 0.0), np.where(moving & (v1 > 0.0), a1, 0.0)
    return ok


def greedy_jerk_profile(s: np.ndarray, cap: np.ndarray, dt: float = 1e-3) -> np.ndarray:
    """Arc length every cycle of a feasible jerk-limited profile under the caps (|a_t| <= A,
    |j_t| <= J, v <= cap: the tangential model of the bounds, the path's own jerk at constant
    speed in the caps): each cycle the largest jerk of JERK_CHOICES whose state can still brake
    within the caps (brakes_within). An upper bound on the least time of that model, so the
    least time lies between the forced bound and this."""
    caps = CapRange(s, np.maximum(cap, CRAWL_MM_S))
    jerks = JERK_CHOICES * JERK
    pos, v, a, out = 0.0, 0.0, 0.0, [0.0]
    while pos < s[-1] - 1e-6:
        s1, v1, a1 = step(np.full(len(jerks), pos), np.full(len(jerks), v), np.full(len(jerks), a), jerks, dt)
        ok = (np.maximum(v, v1) <= caps.between(np.full(len(jerks), pos), s1) + 1e-9) & brakes_within(caps, s1, v1, a1, dt)
        k = int(np.argmax(ok)) if ok.any() else len(jerks) - 1
        pos, v, a = float(s1[k]), float(v1[k]), float(a1[k])
        out.append(min(pos, float(s[-1])))
    return np.array(out)


CLASSES = ("cruise", "dip", "stop", "rapid")


def ramp_up(v0_mm_s: float, feed_mm_s: float, step_s: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """(t, s) of the fastest jerk-limited ramp from v0 at a_t = 0 to F (a_t back at 0 there):
    jerk J up to A (or to sqrt(dv J) when dv < A^2 / J), A held, jerk -J down."""
    dv = max(feed_mm_s - v0_mm_s, 0.0)
    rise = min(ACCEL / JERK, np.sqrt(dv / JERK))
    hold = max(dv / ACCEL - ACCEL / JERK, 0.0)
    t = np.arange(0.0, 2.0 * rise + hold + step_s, step_s)
    accel = JERK * np.minimum(np.minimum(t, rise), np.maximum(2.0 * rise + hold - t, 0.0))
    v = v0_mm_s + np.concatenate([[0.0], np.cumsum(0.5 * (accel[1:] + accel[:-1]) * step_s)])
    return t, np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * step_s)])


def side_time_s(v0_mm_s: float, feed_mm_s: float, distance_mm: float) -> float:
    """Least time over ``distance_mm`` from v0 at a_t = 0 under F, A and J (ramp_up, then F)."""
    t, s = ramp_up(v0_mm_s, feed_mm_s)
    if distance_mm <= s[-1]:
        return float(np.interp(distance_mm, s, t))
    return float(t[-1] + (distance_mm - s[-1]) / feed_mm_s)


def stretch_jerk_s(s: np.ndarray, v: np.ndarray, steps: np.ndarray, feed_mm_s: float) -> float:
    """A lower bound on the time over one slow stretch (its steps) with the tangential jerk
    limited: the speed at the stretch's lowest point p is at most v_p (the forced speeds bound
    every admissible profile), and the fastest profile under that one constraint has its minimum
    at p, so a_t = 0 there (a_t is continuous with a jerk limit); from there each side is at
    best ramp_up over its distance, whatever the stretch's ends do."""
    lo, hi = int(steps[0]), int(steps[-1]) + 1
    p = lo + int(np.argmin(v[lo:hi + 1]))
    return (side_time_s(float(v[p]), feed_mm_s, float(s[p] - s[lo]))
            + side_time_s(float(v[p]), feed_mm_s, float(s[hi] - s[p])))


def step_classes(program: Program, s: np.ndarray, v: np.ndarray, blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(class of every step of s, the stretch of slow steps it belongs to: -1 when cruising):
    rapid (a rapid block's step), else cruise where the forced speeds reach the block's feed,
    else a stretch below it that is a stop (it falls below 5 mm/s: a rest, a crawl corner, a
    rapid/feed junction) or a dip."""
    lim = limits(JERK, 0.01)
    step_block = blocks[:-1]
    rapid = np.array([b.kind == BlockKind.RAPID for b in program.blocks])[step_block]
    feed = np.array([lim.feed_for(b.feed_mm_s) for b in program.blocks])[step_block]
    low = np.minimum(v[1:], v[:-1])
    slow = (low < 0.99 * feed) & ~rapid
    first = slow & ~np.concatenate([[False], slow[:-1]])
    stretch = np.where(slow, np.cumsum(first) - 1, -1)
    lowest = np.full(int(np.count_nonzero(first)), np.inf)
    np.minimum.at(lowest, stretch[slow], low[slow])
    cls = np.where(rapid, 3, np.where(slow, np.where(lowest[np.maximum(stretch, 0)] < 5.0, 2, 1), 0))
    return cls, stretch


def plan_steps(trajectory, s: np.ndarray) -> np.ndarray:
    """The plan's time over each step of s (its set-points' travel scaled to the path's length)."""
    step = np.linalg.norm(np.diff(trajectory.position_mm, axis=0), axis=1)
    travelled = np.concatenate([[0.0], np.cumsum(step)]) * s[-1] / max(float(np.sum(step)), 1e-300)
    return time_steps(travelled, trajectory.period_s, s)


def time_steps(travelled_mm: np.ndarray, period_s: float, s: np.ndarray) -> np.ndarray:
    """Time over each step of s of a motion at ``travelled_mm`` every ``period_s``."""
    t = np.arange(len(travelled_mm)) * period_s
    moving = np.concatenate([[True], np.diff(travelled_mm) > 0.0])
    return np.diff(np.interp(s, travelled_mm[moving], t[moving]))


def breakdown(name: str, program: Program) -> list[str]:
    """Where the plan's time goes against the forced bound, step class by step class."""
    lim = limits(JERK, 0.01)
    trajectory = plan_lookahead(program, lim)
    s, cap, _, blocks, _ = caps_and_blocks(program)
    reasons, straight = stop_reasons(program)
    v = forced_speeds(s, cap, reasons)
    bound_dt = forced_steps(s, v, straight)
    plan_dt = plan_steps(trajectory, s)
    greedy_dt = time_steps(greedy_jerk_profile(s, v), 1e-3, s)
    cls, stretch = step_classes(program, s, v, blocks)
    feed = np.array([lim.feed_for(b.feed_mm_s) for b in program.blocks])[blocks[:-1]]
    jerk_dt = bound_dt.copy()  # bound_dt with every slow stretch stretched to its stretch_jerk_s
    for i in range(int(stretch.max(initial=-1)) + 1):
        steps = np.flatnonzero(stretch == i)
        accel_s = float(np.sum(bound_dt[steps]))
        jerk_s = stretch_jerk_s(s, v, steps, float(feed[steps].max()))
        if jerk_s > accel_s > 0.0:
            jerk_dt[steps] *= jerk_s / accel_s
    masks = [cls == k for k in range(len(CLASSES))] + [np.ones(len(cls), dtype=bool)]
    rows = []
    for label, mask in zip(CLASSES + ("all",), masks):
        count = len(np.unique(stretch[mask])) if label in ("dip", "stop") else ""
        bound, jerk, greedy, plan = (float(np.sum(dt[mask])) for dt in (bound_dt, jerk_dt, greedy_dt, plan_dt))
        rows.append(f"| {name} | {label} | {count} | {float(np.sum(np.diff(s)[mask])):.1f} mm | {bound:.2f} s | "
                    f"{jerk:.2f} s | {greedy:.2f} s | {plan:.2f} s | {plan - bound:+.2f} s | {plan - greedy:+.2f} s |")
        print(rows[-1], flush=True)
    return rows


BREAKDOWN = """Where each plan's time goes (J = 50000), step by step of s along the planned path, each step
classed by the forced bound's speeds there: `rapid` (a rapid block), `cruise` (the forced
speeds at the block's feed), else a stretch below the feed that is a `stop` (it falls below
5 mm/s: a rest, a crawl corner, a rapid/feed junction) or a `dip` (a loop or tight curve). The
plan's time over a step: its set-points' travel mapped onto s. Columns:
- forced: the lower bound of the table above (A only on the tangent; J only in the caps, the
  path's jerk at constant speed, and on straight rest-to-rest runs);
- + J at the lowest points: each slow stretch at least its stretch_jerk_s (the speed at its
  lowest point is at most the forced speed there, and a profile bounded only there has a_t = 0
  at that point, so each side is at best a jerk-limited ramp to the feed): still a lower bound;
- tangential J profile: greedy_jerk_profile, a feasible profile with |a_t| <= A, |j_t| <= J
  under the same caps (every 1 ms the largest jerk of +-J, +-J/2, 0 that can still brake to rest
  within the caps): an upper bound on the least time of that tangential model. It leaves out
  the path's normal jerk 3 |c| v a_t + c'_n v^3, which the plan must keep within J: measured
  on the braid's s = 755-800 mm through the path it is above J on 45 % of its cycles (7 of
  809 above 1.5 J, up to 7 J where its discrete jerks nearly stop it in a loop), so it is not
  a plan the machine may run, only how low the tangential model alone goes. Its 1 ms steps of
  five jerks also lose time near rest (it is slower than our plan on the rests and rapids of
  the braid and the V-carve): only its `dip` rows say much.

| program | class | stretches | length | forced | + J at the lowest points | tangential J profile | our plan | plan - forced | plan - tangential J |
|---|---|---|---|---|---|---|---|---|---|"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--write", action="store_true", help="write the section of docs/benchmarks.md")
    parser.add_argument("--no-jerk", action="store_true", help="the bounds without a jerk limit (section bounds_no_jerk)")
    parser.add_argument("--breakdown", action="store_true",
                        help="where each plan's time goes by class of step (section bounds_breakdown; minutes)")
    args = parser.parse_args()
    if args.no_jerk:
        print(NO_JERK + "\n\n" + NO_JERK_HEADER)
        rows = [no_jerk_row(name, program) for name, program in programs().items()]
        if args.write:
            body, detail = table_section("Lower bounds along the path planned without J (T = 1 ms, A = 2500 mm/s^2, "
                                         "tolerance 0.01 mm); `+ rest at rapid/feed` is the tightest that keeps our "
                                         "rule and LinuxCNC's. Issue 24's 0.85x of LinuxCNC is out of reach wherever "
                                         "it is above 0.85x.", NO_JERK_HEADER, rows, NO_JERK)
            write_section("bounds_no_jerk", "Lower bounds without a jerk limit (short-segment CAM programs)", body,
                          "python benchmarks/bench_bounds.py --no-jerk --write", detail=detail)
        return
    if args.breakdown:
        print(BREAKDOWN)
        lines = [line for name, program in programs().items() for line in breakdown(name, program)]
        if args.write:
            totals = [line for line in lines if line.split("|")[2].strip() == "all"]  # each program's whole path
            intro, header = BREAKDOWN.split(" Columns:")[0], BREAKDOWN[BREAKDOWN.index("| program"):]
            write_section("bounds_breakdown", "Jerk-limited bounds: where the plan's time goes",
                          f"{intro}\n\n{header}\n" + "\n".join(totals),
                          "python benchmarks/bench_bounds.py --breakdown --write",
                          detail=BREAKDOWN + "\n" + "\n".join(lines))
        return
    header = ("| program | LinuxCNC 2.9 (no J) | feeds alone | caps | caps + A, the plan's stops | stops: why | "
              "forced (lower bound with J) | our plan, J = 50000 | speed dips | dips x A/J |\n"
              "|---|---|---|---|---|---|---|---|---|---|")
    print(header)
    rows = [row(name, program) for name, program in programs().items()]
    if args.write:
        body, detail = table_section("Lower bounds along the planned path (T = 1 ms, A = 2500 mm/s^2, J = 50000 "
                                     "mm/s^3, tolerance 0.01 mm); `forced`: rest only where the physics or the "
                                     "program force it, a lower bound with J. With J = 50000 LinuxCNC's time (no jerk "
                                     "limit) is out of reach wherever `forced` is above 1.00x.",
                                     header, rows, __doc__.split("\n\n")[1])
        write_section("bounds", "Jerk-limited lower bounds (short-segment CAM programs)", body,
                      "python benchmarks/bench_bounds.py --write", detail=detail)


def table_section(intro: str, header: str, rows: list[str], columns: str) -> tuple[str, str]:
    """(section body, full result) of a bounds table: ``intro`` and the table; the full result
    is ``columns`` (what each column means) and the same table."""
    table = header + "\n" + "\n".join(rows)
    return f"{intro} The columns are defined in the full result.\n\n{table}", f"{columns}\n\n{table}"


if __name__ == "__main__":
    main()
