"""Feed profiles of one program planned by this tree and by an earlier one (issue 24, third
pass): race limits (T = 1 ms, A = 2500 mm/s^2, feeds capped at 200 mm/s, tolerance 0.01 mm),
J = 50000 mm/s^3 or none; the earlier tree's plan made in a child process from its own src.
Also the sharpest corner the plan blends, against the programmed polyline, in the corner's
plane (``--corner``).

Run: python benchmarks/plot_feed_before_after.py --before-src DIR [--program V-carve]
     [--jerk 50000] [--from-s 10] [--to-s 14] [--ymax 3.5] [--out docs/img/feed_before_after.png]
     [--corner docs/img/sharp_corner_blend.png]
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

from benchmarks.bench_blend import limits, programs  # noqa: E402

CHILD = """
import json, sys
sys.path.insert(0, {root!r}); sys.path.insert(0, {src!r})
import nurbsmotion  # from src, before bench_blend puts this tree's src first
assert nurbsmotion.__file__.startswith({src!r}), nurbsmotion.__file__
from benchmarks.bench_blend import limits, programs
from nurbsmotion.planning.lookahead import plan_lookahead
t = plan_lookahead(programs()[{name!r}], limits({jerk!r}, 0.01))
print(json.dumps({{"feed": t.feed_mm_s.tolist(), "stops": t.notes["stops"]}}))
"""


def feed_profile(src: Path, name: str, jerk: float | None) -> tuple[np.ndarray, int]:
    """(feed of every set-point, stops) of the plan by the tree whose src is ``src``."""
    code = CHILD.format(src=str(src), root=str(ROOT), name=name, jerk=jerk)
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    data = json.loads(out.splitlines()[-1])
    return np.array(data["feed"]), int(data["stops"])


def plot_profiles(args: argparse.Namespace) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    jerk = None if args.jerk == "none" else float(args.jerk)
    fig, ax = plt.subplots(figsize=(10, 4))
    for label, src, color in (("before", Path(args.before_src), "C1"), ("this tree", ROOT / "src", "C0")):
        feed, stops = feed_profile(src, args.program, jerk)
        t = np.arange(len(feed)) * 0.001
        keep = (t >= args.from_s) & (t <= args.to_s)
        ax.plot(t[keep], feed[keep], color, lw=1, label=f"{label}: {len(feed) * 0.001:.2f} s, {stops} stops")
    if args.ymax is not None:
        ax.set_ylim(0.0, args.ymax)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("feed (mm/s)")
    ax.set_title(f"{args.program}, J = {args.jerk}: feed profile before and after")
    ax.legend(loc="upper right")
    fig.savefig(args.out, dpi=110, bbox_inches="tight")
    print(f"wrote {args.out}")


def plot_sharpest_corner(name: str, out: Path) -> None:
    """The sharpest blended corner of the plan's path, in the plane of its two lines."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from nurbsmotion.planning.lookahead import planned_pieces
    pieces = planned_pieces(programs()[name], limits(50000.0, 0.01))
    blends = [p for p in pieces if p.corners is not None]

    def cosine(piece) -> float:  # type: ignore[no-untyped-def]
        c, k = piece.corners, piece.corner
        return float(np.dot(c.incoming.direction[k], c.outgoing.direction[k]))

    blend = min(blends, key=cosine)
    c, k = blend.corners, blend.corner
    t_in, t_out = c.incoming.direction[k], c.outgoing.direction[k]
    corner = c.incoming.start[k] + c.incoming.length_mm[k] * t_in
    e1 = t_in
    e2 = t_out - np.dot(t_out, e1) * e1
    e2 /= np.linalg.norm(e2)
    points = np.pad(blend.curve.points(np.linspace(0.0, 1.0, 300)), ((0, 0), (0, 3 - blend.curve.dim)))
    reach = 1.5 * float(np.max(np.linalg.norm(points - corner, axis=1)))

    def plane(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rel = np.atleast_2d(p) - corner
        return rel @ e1, rel @ e2

    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(*plane(np.array([corner - reach * t_in, corner, corner + reach * t_out])), "k--", lw=1,
            label="programmed lines")
    turn = np.degrees(np.arccos(np.clip(cosine(blend), -1.0, 1.0)))
    ax.plot(*plane(points), "C3-", lw=2, label=f"quintic G2 blend within 0.01 mm ({turn:.0f} deg corner)")
    ax.set_aspect("equal")
    ax.legend(loc="best")
    ax.set_title(f"{name}, block {blend.block + 1}: the sharpest blended corner (in its plane)")
    ax.set_xlabel("mm along the incoming line")
    ax.set_ylabel("mm across, towards the outgoing line")
    fig.savefig(out, dpi=110, bbox_inches="tight")
    print(f"wrote {out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--before-src", required=True, help="src/ of the earlier tree")
    parser.add_argument("--program", default="V-carve", choices=["HSM_test", "braid F7000", "V-carve"])
    parser.add_argument("--jerk", default="50000")
    parser.add_argument("--from-s", type=float, default=10.0)
    parser.add_argument("--to-s", type=float, default=14.0)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "img" / "feed_before_after.png")
    parser.add_argument("--ymax", type=float, default=None, help="feed axis up to this (the cuts under the rapids)")
    parser.add_argument("--corner", type=Path, default=None, help="also plot the sharpest blended corner here")
    args = parser.parse_args()
    if args.corner is not None:
        plot_sharpest_corner(args.program, args.corner)
    plot_profiles(args)


if __name__ == "__main__":
    main()
