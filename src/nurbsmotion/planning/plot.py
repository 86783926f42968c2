"""One PNG per run, like Wang's Figures 5-9: path with control polygon, curvature, feed,
chord error with δ_max, resultant acceleration with a_max, jerk (all measured).

matplotlib is an optional extra (``pip install 'nurbsmotion[plots]'``), imported lazily
with the Agg backend so no display is needed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nurbsmotion.errors import InputError
from nurbsmotion.planning.limits import PlanLimits
from nurbsmotion.planning.measure import Measurements
from nurbsmotion.planning.trajectory import Trajectory
from nurbsmotion.program import BlockKind, Program


def require_matplotlib():
    """The pyplot module (Agg backend); InputError naming --plot when matplotlib is missing."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise InputError("--plot", "matplotlib is not installed: pip install 'nurbsmotion[plots]'") from None
    return plt


def curvature_at_setpoints(program: Program, trajectory: Trajectory) -> np.ndarray:
    kappa = np.zeros(len(trajectory))
    for b in np.unique(trajectory.block):
        rows = trajectory.block == b
        kappa[rows] = program.blocks[int(b)].curve.curvature(trajectory.u[rows])
    return kappa


def plot_run(path: str | Path, program: Program, trajectory: Trajectory, m: Measurements, limits: PlanLimits) -> None:
    """Write the six-panel figure to ``path`` (PNG)."""
    plt = require_matplotlib()
    t = trajectory.t_s
    fig = plt.figure(figsize=(14, 10))
    fig.suptitle(f"{program.name}: {trajectory.algorithm}, T = {limits.period_s * 1000:g} ms, "
                 f"{m.cycles} cycles, {m.duration_s:.3f} s")
    ax = fig.add_subplot(2, 3, 1, projection="3d")
    p = trajectory.position_mm
    ax.plot(p[:, 0], p[:, 1], p[:, 2], lw=1.2, label="set-points")
    for i, block in enumerate(program.blocks):
        if block.kind == BlockKind.NURBS:
            cp = block.curve.control_points
            ax.plot(cp[:, 0], cp[:, 1], cp[:, 2], "--o", ms=2, lw=0.6, color="grey",
                    label="control polygon" if i == 0 else None)
    ax.set_xlabel("X mm")
    ax.set_ylabel("Y mm")
    ax.set_zlabel("Z mm")
    ax.legend(loc="upper left", fontsize=7)
    ax.set_title("path")
    panels = [
        ("curvature (1/mm)", curvature_at_setpoints(program, trajectory), None, None),
        ("feed (mm/s)", m.speed_mm_s, None, trajectory.feed_mm_s),
        ("chord error (µm)", m.chord_error_mm * 1000.0, limits.chord_error_mm * 1000.0, None),
        ("resultant acceleration (mm/s²)", m.accel_mm_s2, limits.max_accel_mm_s2, None),
        ("jerk (mm/s³)", m.jerk_mm_s3, limits.max_jerk_mm_s3, None),
    ]
    for k, (title, values, limit, planned) in enumerate(panels, start=2):
        axis = fig.add_subplot(2, 3, k)
        axis.plot(t, values, lw=0.8, label="measured" if planned is not None else None)
        if planned is not None:
            axis.plot(t, planned, lw=0.6, ls="--", label="commanded")
            axis.legend(fontsize=7)
        if limit is not None:
            axis.axhline(limit, color="red", lw=0.8, ls=":")
        axis.set_title(title)
        axis.set_xlabel("t (s)")
        axis.grid(alpha=0.3)
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=100)
    except OSError as err:
        raise InputError(str(path), f"cannot write plot: {err.strerror or err}") from None
    finally:
        plt.close(fig)
