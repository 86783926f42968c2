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
  with a jerk limit each dip's change of acceleration takes about A / J more.

Run: python benchmarks/bench_bounds.py [--write]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))

from benchmarks._report import write_section  # noqa: E402
from benchmarks.bench_blend import LINUXCNC_S, limits, programs  # noqa: E402
from nurbsmotion.planning.lookahead import plan_lookahead, planned_pieces  # noqa: E402
from nurbsmotion.program import Program  # noqa: E402

JERK = 50000.0
ACCEL = 2500.0
STEP_MM = 0.01


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
    line = (f"| {name} | {linuxcnc:.2f} s | {feeds_s:.2f} s | {time_s(s, cap):.2f} s ({time_s(s, cap) / linuxcnc:.2f}x) | "
            f"{accel_s:.2f} s ({accel_s / linuxcnc:.2f}x) | {len(stops)} | {plan_s:.2f} s ({plan_s / linuxcnc:.2f}x) | "
            f"{dips} | {dips * ACCEL / JERK:.1f} s |")
    print(line, flush=True)
    return line


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--write", action="store_true", help="write the section of docs/benchmarks.md")
    args = parser.parse_args()
    header = ("| program | LinuxCNC 2.9 (no J) | feeds alone | caps | caps + A, the plan's stops | stops | "
              "our plan, J = 50000 | speed dips | dips x A/J |\n|---|---|---|---|---|---|---|---|---|")
    print(header)
    rows = [row(name, program) for name, program in programs().items()]
    if args.write:
        body = (__doc__.split("\n\n")[1] + "\n\n" + header + "\n" + "\n".join(rows))
        write_section("bounds", "Jerk-limited lower bounds (short-segment CAM programs)", body,
                      "python benchmarks/bench_bounds.py --write")


if __name__ == "__main__":
    main()
