"""docs/img/smoothing_run.png: one run of grbl_HSM_test.nc, its G01 polyline against the fitted
cubic (geometry/polyline_fit.py) with the tolerance band, whole and zoomed where they differ most.

Run: python benchmarks/plot_smoothing_run.py [--tolerance MM] [--run I] [--out PATH]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from nurbsmotion.geometry.polyline_fit import deviations, smooth_polyline  # noqa: E402
from nurbsmotion.program import read_program  # noqa: E402
from nurbsmotion.program.line_chains import line_chains  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PROGRAM = ROOT / "tests" / "data" / "gcode" / "grbl_HSM_test.nc"


def band(ax, points: np.ndarray, tolerance_mm: float) -> None:
    """The tolerance band around the polyline in XY: each segment widened to a rectangle and each
    vertex to a disc of radius tolerance_mm (their union is the set within the tolerance)."""
    from matplotlib.patches import Circle, Polygon

    for a, b in zip(points[:-1, :2], points[1:, :2]):
        d = b - a
        n = np.array([-d[1], d[0]]) / max(float(np.hypot(*d)), 1e-12) * tolerance_mm
        ax.add_patch(Polygon([a + n, b + n, b - n, a - n], closed=True, color="#cfe3ff", lw=0))
    for p in points[:, :2]:
        ax.add_patch(Circle(p, tolerance_mm, color="#cfe3ff", lw=0))


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tolerance", type=float, default=0.01)
    parser.add_argument("--run", type=int, default=0, help="which fitted run of the program")
    parser.add_argument("--out", default=str(ROOT / "docs" / "img" / "smoothing_run.png"))
    args = parser.parse_args()
    chain = line_chains(read_program(PROGRAM))[0]
    fit = smooth_polyline(chain.points, args.tolerance, chain.feeds_mm_s, chain.breaks).fitted[args.run]
    points = fit.span.vertices(chain.points)
    curve = fit.curve
    x = curve.derivatives(np.linspace(curve.u_min, curve.u_max, 20 * len(points)), 0)[0]
    u_vertex, d_vertex, u_sample, d_sample = deviations(curve, points)
    worst = curve.derivatives(np.array([u_sample[np.argmax(d_sample)]]), 0)[0][0]
    fig, (whole, zoom) = plt.subplots(1, 2, figsize=(13, 6.2))
    for ax in (whole, zoom):
        band(ax, points, args.tolerance)
        ax.plot(points[:, 0], points[:, 1], "-o", color="#1f4e9c", ms=2.5, lw=0.8,
                label=f"G01 polyline ({len(points)} vertices)")
        ax.plot(x[:, 0], x[:, 1], "-", color="#d62728", lw=1.2,
                label=f"fitted cubic ({len(curve.control_points)} control points)")
        ax.set_aspect("equal")
        ax.set_xlabel("X / mm")
        ax.set_ylabel("Y / mm")
    whole.plot(curve.control_points[:, 0], curve.control_points[:, 1], "s", color="#2ca02c", ms=3,
               label="control points")
    whole.set_title(f"{PROGRAM.name}, blocks {chain.block_of_segment(fit.span.first) + 1}-"
                    f"{chain.block_of_segment(fit.span.last - 1) + 1}")
    whole.legend(loc="best", fontsize=8)
    half = 12 * args.tolerance
    zoom.set_xlim(worst[0] - half, worst[0] + half)
    zoom.set_ylim(worst[1] - half, worst[1] + half)
    zoom.set_title(f"zoom where the curve is farthest from the polyline: {d_sample.max() * 1000:.1f} um\n"
                   f"(band: +-{args.tolerance * 1000:g} um; largest vertex distance {d_vertex.max() * 1000:.1f} um)")
    fig.tight_layout()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(args.out)


if __name__ == "__main__":
    main()
