"""Lines and circular arcs as exact NURBS, so the planner only ever sees NurbsCurve; and
as what they are (LineShape, ArcShape: a few numbers, closed-form length), for programs
that keep them compactly and build the NURBS only when it is asked for.

A circular arc of sweep theta <= 90 deg is exactly the rational quadratic Bezier with
control points P0, P1 (intersection of the end tangents), P2 and weights 1, cos(theta/2), 1
(Piegl & Tiller, algorithm A7.1). Longer arcs are split into equal segments of at most
90 deg joined with double knots.

A helix (an arc whose end rises by ``rise_mm`` along the normal) has no exact NURBS form:
each segment's rise is interpolated by its rational quadratic (control heights z0,
(z0+z1)/2, z1), so the height along the segment is z0 + dz f(u) with f(u) = (w B1/2 + B2)/W
instead of z0 + dz theta(u)/delta. Its projection is the exact circle; the height differs
from the true helix by at most HELIX_SHAPE * (delta / 90 deg)^2 * dz (0.0211 dz at 90 deg,
measured), so segments are made short enough to keep that below ``helix_tolerance_mm``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Sequence, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from nurbsmotion.geometry.nurbs import NurbsCurve

FULL_TURN = 2.0 * math.pi
HELIX_SHAPE = 0.0212  # max |f(u) - theta(u)/delta| of a 90 deg segment (bound above the measured 0.02109)
HELIX_TOLERANCE_MM = 1e-4  # largest height error of a helix segment (0.1 um, far below any chord tolerance)


_LINE_WEIGHTS = np.ones(2)
_LINE_KNOTS = np.array([0.0, 0.0, 1.0, 1.0])
_LINE_WEIGHTS.setflags(write=False)
_LINE_KNOTS.setflags(write=False)


def line_curve(start: ArrayLike, end: ArrayLike) -> NurbsCurve:
    """A straight segment as a degree-1 NURBS on [0, 1] (constant parametric speed).

    Two finite points of one dimension make a valid segment by construction, so the general
    validation (NurbsCurve.create, 0.17 ms) runs only when they do not: readers build one
    segment per G1 line (15 000 in a CAM file)."""
    points = np.array([start, end], dtype=np.float64)
    if points.ndim != 2 or not np.isfinite(points).all():
        return NurbsCurve.create(1, points, [1.0, 1.0], [0.0, 0.0, 1.0, 1.0])  # create names the problem
    points.setflags(write=False)
    return NurbsCurve(1, points, _LINE_WEIGHTS, _LINE_KNOTS)


@dataclass(frozen=True, slots=True)
class LineShape:
    """A straight segment from ``start`` to ``end`` (3-vectors, mm); ``curve()`` is line_curve."""

    start: NDArray[np.float64]
    end: NDArray[np.float64]

    def curve(self) -> NurbsCurve:
        return line_curve(self.start, self.end)

    @property
    def length_mm(self) -> float:
        """|end - start|."""
        return math.dist(self.start.tolist(), self.end.tolist())


@dataclass(frozen=True, slots=True)
class ArcShape:
    """A circular arc or helix as arc_curve takes it: about ``centre``, turning ``sweep_rad``
    about the unit axis ``normal`` from ``start`` to the programmed ``end``, rising
    ``rise_mm`` along the normal; ``curve()`` is that arc_curve."""

    start: NDArray[np.float64]
    end: NDArray[np.float64]
    centre: NDArray[np.float64]
    sweep_rad: float
    normal: tuple[float, float, float]
    rise_mm: float

    def curve(self) -> NurbsCurve:
        return arc_curve(self.centre, self.start, self.sweep_rad, self.normal, rise_mm=self.rise_mm, end=self.end)

    @property
    def length_mm(self) -> float:
        """sqrt((r sweep)^2 + rise^2), r the radius in the plane normal to the axis."""
        return float(arc_lengths_mm(self.start[None, :], self.centre[None, :], np.asarray(self.normal, float)[None, :],
                                    np.array([self.sweep_rad]), np.array([self.rise_mm]))[0])


def line_lengths_mm(starts: NDArray[np.float64], ends: NDArray[np.float64]) -> NDArray[np.float64]:
    """|end - start| of many segments, rows (n, 3)."""
    return np.sqrt(np.einsum("ij,ij->i", ends - starts, ends - starts))


def arc_radii_mm(starts: NDArray[np.float64], centres: NDArray[np.float64], normals: NDArray[np.float64]) -> NDArray[np.float64]:
    """|start - centre| in the plane normal to the (unit) normal, rows (n, 3)."""
    radial = starts - centres
    radial = radial - np.einsum("ij,ij->i", radial, normals)[:, None] * normals
    return np.sqrt(np.einsum("ij,ij->i", radial, radial))


def arc_lengths_mm(starts: NDArray[np.float64], centres: NDArray[np.float64], normals: NDArray[np.float64],
                   sweeps_rad: NDArray[np.float64], rises_mm: NDArray[np.float64]) -> NDArray[np.float64]:
    """Length of circular arcs and helices: sqrt((r sweep)^2 + rise^2) (the helix unrolled)."""
    return np.hypot(arc_radii_mm(starts, centres, normals) * sweeps_rad, rises_mm)


def arc_sweep_rad(start_angle: float, end_angle: float, clockwise: bool, full_circle_if_equal: bool = True) -> float:
    """Signed sweep from start to end angle: negative clockwise, in (-2 pi, 2 pi]."""
    sweep = (end_angle - start_angle) % FULL_TURN
    if clockwise:
        sweep = sweep - FULL_TURN if sweep > 0 else (-FULL_TURN if full_circle_if_equal else 0.0)
    elif sweep == 0 and full_circle_if_equal:
        sweep = FULL_TURN
    return sweep


def helix_segments(sweep_rad: float, rise_mm: float, tolerance_mm: float = HELIX_TOLERANCE_MM) -> int:
    """Fewest equal segments of at most 90 deg whose height error (module docstring) is within tolerance."""
    quarters = abs(sweep_rad) / (math.pi / 2)
    n = max(1, math.ceil(quarters - 1e-9))
    if rise_mm == 0:
        return n
    # error(n) = HELIX_SHAPE * (quarters / n)^2 * |rise| / n  <=  tolerance
    needed = math.ceil((HELIX_SHAPE * quarters**2 * abs(rise_mm) / tolerance_mm) ** (1.0 / 3.0) - 1e-9)
    return max(n, needed)


def arc_curve(center: ArrayLike, start: ArrayLike, sweep_rad: float, normal: ArrayLike = (0.0, 0.0, 1.0),
              rise_mm: float = 0.0, helix_tolerance_mm: float = HELIX_TOLERANCE_MM,
              end: ArrayLike | None = None) -> NurbsCurve:
    """Circular arc around ``center`` from ``start``, turning ``sweep_rad`` about ``normal``.

    Positive sweep is counter-clockwise seen from the tip of the normal (right-hand rule).
    The radius is |start - center| measured in the plane normal to ``normal``; the end is
    ``rise_mm`` higher along the normal than the start (a helix when not zero). With ``end``
    (a G02/G03's programmed end), the first and last control points are ``start`` and
    ``end`` themselves: the computed ones differ from them by rounding only.

    Plain float arithmetic on the 3-vectors and one array per field at the end: numpy's
    per-call overhead on 3-vectors cost more than the arithmetic (readers build one arc per
    G02/G03 line). The result is valid by construction (degree 2, 2 s + 1 points, weights
    1 and cos(delta / 2) >= cos 45 deg, the knots below), so only non-finite input can make
    it invalid: NurbsCurve.create then names the problem.
    """
    cx, cy, cz = _xyz(center, "center")
    sx, sy, sz = _xyz(start, "start")
    nx, ny, nz = _xyz(normal, "normal")
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    if not norm > 0:
        raise ValueError("arc normal must be a non-zero vector")
    nx, ny, nz = nx / norm, ny / norm, nz / norm
    rx, ry, rz = sx - cx, sy - cy, sz - cz
    height = rx * nx + ry * ny + rz * nz
    ux, uy, uz = rx - height * nx, ry - height * ny, rz - height * nz  # in-plane radial: the x axis
    radius = math.sqrt(ux * ux + uy * uy + uz * uz)
    if radius <= 0 or abs(sweep_rad) <= 0:
        raise ValueError("arc needs a positive radius and a non-zero sweep")
    ux, uy, uz = ux / radius, uy / radius, uz / radius
    vx, vy, vz = ny * uz - nz * uy, nz * ux - nx * uz, nx * uy - ny * ux  # y axis = n x u
    ox, oy, oz = cx + height * nx, cy + height * ny, cz + height * nz
    segments = helix_segments(sweep_rad, rise_mm, helix_tolerance_mm)
    delta = sweep_rad / segments
    w_mid = math.cos(delta / 2.0)

    def on_circle(angle: float, scale: float = 1.0) -> tuple[float, float, float]:
        lift = rise_mm * angle / sweep_rad
        r, c, s = scale * radius, math.cos(angle), math.sin(angle)
        return (ox + lift * nx + r * (c * ux + s * vx), oy + lift * ny + r * (c * uy + s * vy),
                oz + lift * nz + r * (c * uz + s * vz))

    points = [on_circle(0.0) if end is None else (sx, sy, sz)]
    for i in range(segments):
        a0 = i * delta
        points.append(on_circle(a0 + delta / 2.0, 1.0 / w_mid))  # tangent intersection, mid height
        points.append(on_circle(a0 + delta))
    if end is not None:
        points[-1] = _xyz(end, "end")
    if not math.isfinite(sum(sum(p) for p in points)):  # a NaN or infinity anywhere (or an overflow)
        return NurbsCurve.create(2, points, _arc_weights(segments, w_mid), _arc_knots(segments))  # names it
    array = np.array(points)
    array.setflags(write=False)
    return NurbsCurve(2, array, _arc_weights(segments, w_mid), _arc_knots(segments))


def _xyz(v: ArrayLike, name: str) -> tuple[float, float, float]:
    """Three floats from a point or vector (an ndarray's tolist() is the cheap path)."""
    values: list[Any] = v.tolist() if isinstance(v, np.ndarray) else list(cast(Sequence[Any], v))
    if len(values) != 3:
        raise ValueError(f"arc {name} must have 3 coordinates, got {len(values)}")
    return float(values[0]), float(values[1]), float(values[2])


def _arc_weights(segments: int, w_mid: float) -> NDArray[np.float64]:
    """1, w, 1, w, ..., 1: the ends of the segments and their tangent intersections."""
    weights = np.array([1.0] + [w_mid, 1.0] * segments)
    weights.setflags(write=False)
    return weights


@functools.lru_cache(maxsize=64)
def _arc_knots(segments: int) -> NDArray[np.float64]:
    """0 0 0, i/s twice for i = 1..s-1, 1 1 1: equal segments joined with double knots
    (shared and read-only: a program's arcs mostly have 1 to 4 segments)."""
    inner = np.repeat(np.arange(1, segments) / segments, 2)
    knots = np.concatenate([[0.0, 0.0, 0.0], inner, [1.0, 1.0, 1.0]])
    knots.setflags(write=False)
    return knots
