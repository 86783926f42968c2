"""The feed profile of a smoothed run with the jerk limit (issue 24): grbl's braid_cut2d.nc at
F7000 (race limits: T = 1 ms, A = 2500 mm/s^2, J = 50000 mm/s^3, tolerance 0.01 mm), a stretch
of its plan, smoothed and blended only, with the curvature of the planned path under the feed.

Run: python benchmarks/plot_smoothing_feed.py [--from-s 5] [--to-s 8] [--out docs/img/smoothing_feed.png]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))

from benchmarks.bench_blend import limits, programs  # noqa: E402
from nurbsmotion.planning.lookahead import plan_lookahead  # noqa: E402
from nurbsmotion.planning.lookahead.planned_path import PlannedPath  # noqa: E402


def curvature_along(path: PlannedPath, trajectory) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Curvature of the planned path at every set-point."""
    rows = path.rows(trajectory)
    out = np.zeros(len(rows.u))
    for k in np.unique(rows.block).tolist():
        curve = path.program.blocks[k].curve
        at = rows.block == k
        if curve.degree > 1:
            out[at] = curve.curvature(rows.u[at])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--from-s", type=float, default=5.0)
    parser.add_argument("--to-s", type=float, default=8.0)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "img" / "smoothing_feed.png")
    args = parser.parse_args()
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    program = programs()["braid F7000"]
    fig, axes = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    for smoothing, style in ((False, "C1-"), (True, "C0-")):
        plan_limits = limits(50000.0, 0.01, smoothing)
        trajectory = plan_lookahead(program, plan_limits)
        t = np.arange(len(trajectory.u)) * plan_limits.period_s
        shown = (t >= args.from_s) & (t <= args.to_s)
        label = f"{'smoothed' if smoothing else 'blended only'} ({trajectory.duration_s:.2f} s in all)"
        axes[0].plot(t[shown], trajectory.feed_mm_s[shown], style, label=label)
        kappa = curvature_along(PlannedPath.of(program, plan_limits), trajectory)
        axes[1].plot(t[shown], kappa[shown], style, lw=1)
    axes[0].set_ylabel("feed (mm/s)")
    axes[0].legend(loc="upper right")
    axes[0].set_title("braid_cut2d F7000, J = 50000 mm/s^3, tolerance 0.01 mm")
    axes[1].set_ylabel("curvature (1/mm)")
    axes[1].set_yscale("symlog", linthresh=0.01)
    axes[1].set_xlabel("time in the plan (s)")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=90, bbox_inches="tight")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
