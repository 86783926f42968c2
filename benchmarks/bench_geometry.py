"""Geometry speed: vectorised NURBS evaluation vs scipy, and the per-cycle scalar path.

Targets (issue 2): 1,000,000 points with first and second derivatives on Wang's Table 1
curve within 2x of scipy's BSpline doing the same (homogeneous B-spline + quotient rule)
in the same run; scalar point + 2 derivatives <= 10 us per call.

Run: python benchmarks/bench_geometry.py [--points N] [--repeat R]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import write_section  # noqa: E402
from nurbsmotion.geometry import NurbsCurve  # noqa: E402
from tests.conftest import WANG_KNOTS, WANG_POINTS, WANG_WEIGHTS  # noqa: E402


def best_of(repeat: int, fn) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def scipy_same(curve: NurbsCurve, u: np.ndarray):
    from scipy.interpolate import BSpline

    spline = BSpline(curve.knots, curve.homogeneous, curve.degree)
    a0, a1, a2 = spline(u), spline(u, 1), spline(u, 2)
    w0, w1, w2 = a0[:, -1:], a1[:, -1:], a2[:, -1:]
    x = a0[:, :-1] / w0
    x1 = (a1[:, :-1] - w1 * x) / w0
    x2 = (a2[:, :-1] - 2 * w1 * x1 - w2 * x) / w0
    return x, x1, x2


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    curve = NurbsCurve.create(2, WANG_POINTS, WANG_WEIGHTS, WANG_KNOTS)
    u = np.random.default_rng(1).uniform(0, 1, args.points)
    ours = best_of(args.repeat, lambda: curve.derivatives(u, 2))
    theirs = best_of(args.repeat, lambda: scipy_same(curve, u))
    ref = scipy_same(curve, u)
    got = curve.derivatives(u, 2)
    err = max(float(np.abs(got[k] - ref[k]).max() / np.abs(ref[k]).max()) for k in range(3))
    calls = 200_000
    grid = np.linspace(0, 1, calls).tolist()
    t0 = time.perf_counter()
    for value in grid:
        curve.point_and_derivatives(value)
    scalar_us = (time.perf_counter() - t0) / calls * 1e6
    length = curve.length
    body = f"""
| measurement (Wang Table 1 curve, degree 2, 17 points) | result | target |
|---|---|---|
| vectorised x, x', x'' at {args.points:,} points (best of {args.repeat}) | {ours * 1e3:.0f} ms | |
| scipy BSpline (3 calls) + quotient rule, same points | {theirs * 1e3:.0f} ms | |
| ratio ours / scipy | {ours / theirs:.2f}x | <= 2x {'(met)' if ours <= 2 * theirs else '(NOT met)'} |
| largest relative difference to scipy | {err:.1e} | |
| scalar point + 2 derivatives, {calls:,} calls | {scalar_us:.2f} us/call | <= 10 us {'(met)' if scalar_us <= 10 else '(NOT met)'} |
| arc length | {length:.6f} mm | about 1028.1 mm (paper) |
"""
    write_section("geometry", "Geometry", body, "python benchmarks/bench_geometry.py")


if __name__ == "__main__":
    main()
