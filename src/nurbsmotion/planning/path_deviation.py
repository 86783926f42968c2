"""Distance of many points to a program's path: the ruler for "how far did the machine stray".

The path is every block of the program (rapids included), in machine coordinates, split
into elements the distance is exact for:

- a degree-1 curve: the straight segments between its control points; distance of p to
  segment [a, b] = |p - (a + t (b - a))| with t = clamp((p - a).(b - a) / |b - a|^2, 0, 1);
- a circular arc span (rational quadratic Bezier P0, P1, P2 with weight w, |P0 P1| = |P1 P2|
  and w = cos of the angle between P0 P1 and P0 P2: a circle, geometry.primitives): centre
  C = P1 + (M - P1) / (1 - w^2) with M = (P0 + P2) / 2, radius R = |P0 - C|, sweep delta
  with cos(delta / 2) = w. Distance of p with height z over the arc's plane and in-plane
  radius rho at angle phi: sqrt(z^2 + (rho - R)^2) when 0 <= phi <= delta, else the nearer
  end point;
- anything else (G5.2 NURBS, helix spans, which are not circles): a polyline through points
  sampled at most ``sample_step(kappa)`` apart, whose sag kappa ds^2 / 8 stays within
  ``sample_tolerance_mm``; the distance is then exact to that tolerance.

Search: every element is cut into pieces no longer than the cell size h (arcs by angle,
sagging at most h / 8 at 90 deg) and each piece registered in the cells of a uniform grid
its bounding box, widened by the search radius r = h / 2, overlaps (at most 3 x 3 x 3). An
element within r of a point then lies in the point's cell; points whose nearest
registered element is farther than r (or whose cell is empty) are searched again on a grid
CELL_GROWTH times coarser, and after CELL_LEVELS grids against every element. Exact,
vectorised, and about linear in points + path length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.program import Program

SAMPLE_TOLERANCE_MM = 1e-4  # sag of the polyline standing for a curve that is no line or circle
CELL_MM = 0.1  # finest grid cell of the search; its search radius is half of it
CELL_GROWTH = 8.0  # each coarser grid's cell over the previous one's
CELL_LEVELS = 3  # grids tried before the exhaustive search (0.1, 0.8, 6.4 mm)
LINE_SAG_MM = 1e-9  # an arc span sagging less than this from its chord is measured as the chord
CIRCLE_REL_TOLERANCE = 1e-9  # |P0P1| = |P1P2| and w = cos(angle at P0), relative: the span is a circle
BRUTE_CHUNK_PAIRS = 4_000_000  # point x element pairs per vectorised block of the exhaustive search

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class PathElements:
    """A path as straight segments (start, end) and circular arcs (centre, unit axes u and
    v = normal x u in the arc's plane, radius, sweep from u towards v in (0, pi])."""

    seg_start: FloatArray  # (S, 3)
    seg_end: FloatArray  # (S, 3)
    arc_center: FloatArray  # (C, 3)
    arc_u: FloatArray  # (C, 3)
    arc_v: FloatArray  # (C, 3)
    arc_radius: FloatArray  # (C,)
    arc_sweep_rad: FloatArray  # (C,)

    @property
    def segment_count(self) -> int:
        return len(self.seg_start)

    @property
    def arc_count(self) -> int:
        return len(self.arc_center)

    @property
    def arc_start(self) -> FloatArray:
        return self.arc_center + self.arc_radius[:, None] * self.arc_u

    @property
    def arc_end(self) -> FloatArray:
        c, s = np.cos(self.arc_sweep_rad)[:, None], np.sin(self.arc_sweep_rad)[:, None]
        return self.arc_center + self.arc_radius[:, None] * (c * self.arc_u + s * self.arc_v)


@dataclass(frozen=True)
class CircleSpan:
    center: tuple[float, float, float]
    u: tuple[float, float, float]
    v: tuple[float, float, float]
    radius: float
    sweep_rad: float


# ---- the path as elements ---------------------------------------------------------------------------
def circle_span(p0: FloatArray, p1: FloatArray, p2: FloatArray, w: float) -> CircleSpan | None:
    """The circle a rational quadratic Bezier span is, or None when it is not one (module docstring)."""
    a, b, chord = p1 - p0, p2 - p1, p2 - p0
    la, lb, lc = float(np.linalg.norm(a)), float(np.linalg.norm(b)), float(np.linalg.norm(chord))
    if not (la > 0 and lc > 0 and 0 < w < 1) or abs(la - lb) > CIRCLE_REL_TOLERANCE * la:
        return None
    if abs(float(a @ chord) / (la * lc) - w) > CIRCLE_REL_TOLERANCE:
        return None
    mid = 0.5 * (p0 + p2)
    center = p1 + (mid - p1) / (1.0 - w * w)
    radius = float(np.linalg.norm(p0 - center))
    u = (p0 - center) / radius
    v = (p1 - center) - float((p1 - center) @ u) * u
    v /= float(np.linalg.norm(v))
    sweep = 2.0 * math.acos(w)
    return CircleSpan(tuple(center), tuple(u), tuple(v), radius, sweep)


def sample_step_mm(kappa_per_mm: float, tolerance_mm: float) -> float:
    """Longest chord whose sag kappa ds^2 / 8 stays within the tolerance."""
    return math.sqrt(8.0 * tolerance_mm / kappa_per_mm) if kappa_per_mm > 0 else math.inf


def sampled_polyline(curve: NurbsCurve, u0: float, u1: float, tolerance_mm: float) -> FloatArray:
    """Points of the curve between u0 and u1, at most sample_step_mm(max curvature) apart in arc length."""
    probe = np.linspace(u0, u1, 257)
    kappa = float(np.max(np.asarray(curve.curvature(probe))))
    s0, s1 = float(curve.arc_length(u0)), float(curve.arc_length(u1))
    step = min(sample_step_mm(kappa * 1.5, tolerance_mm), max(s1 - s0, 1e-12))  # 1.5: curvature between probes
    count = max(2, math.ceil((s1 - s0) / step) + 1)
    u = np.asarray(curve.u_at_arc_length(np.linspace(s0, s1, count)), dtype=np.float64)
    u[0], u[-1] = u0, u1
    return curve.points(u)


def is_arc_layout(curve: NurbsCurve) -> bool:
    """Degree 2 with every inner knot doubled: independent Bezier spans P[2i], P[2i+1], P[2i+2]."""
    knots = curve.knots
    inner = knots[3:-3]
    return (curve.degree == 2 and len(curve.control_points) % 2 == 1 and len(inner) == len(curve.control_points) - 3
            and bool(np.all(inner[0::2] == inner[1::2])))


class _Collector:
    def __init__(self, tolerance_mm: float) -> None:
        self.tolerance_mm = tolerance_mm
        self.starts: list[FloatArray] = []
        self.ends: list[FloatArray] = []
        self.circles: list[CircleSpan] = []

    def polyline(self, points: FloatArray) -> None:
        self.starts.append(points[:-1])
        self.ends.append(points[1:])

    def curve(self, curve: NurbsCurve) -> None:
        points = np.asarray(curve.control_points, dtype=np.float64)
        if curve.degree == 1:
            self.polyline(points)
        elif is_arc_layout(curve):
            breaks = curve.knots[2:-1:2]  # 0, 1/s, ..., 1
            for i in range((len(points) - 1) // 2):
                self.arc_span(curve, points[2 * i: 2 * i + 3], float(curve.weights[2 * i + 1]),
                              float(breaks[i]), float(breaks[i + 1]))
        else:
            self.polyline(sampled_polyline(curve, curve.u_min, curve.u_max, self.tolerance_mm))

    def arc_span(self, curve: NurbsCurve, p: FloatArray, w: float, u0: float, u1: float) -> None:
        sag = float(np.linalg.norm(0.5 * (p[0] + p[2]) - p[1])) * w / (1.0 + w)
        if sag < LINE_SAG_MM:
            self.polyline(p[[0, 2]])
            return
        span = circle_span(p[0], p[1], p[2], w)
        if span is None:
            self.polyline(sampled_polyline(curve, u0, u1, self.tolerance_mm))
        else:
            self.circles.append(span)

    def elements(self) -> PathElements:
        empty = np.zeros((0, 3))
        circles = self.circles
        return PathElements(
            np.concatenate(self.starts) if self.starts else empty,
            np.concatenate(self.ends) if self.ends else empty,
            np.array([c.center for c in circles]).reshape(-1, 3), np.array([c.u for c in circles]).reshape(-1, 3),
            np.array([c.v for c in circles]).reshape(-1, 3), np.array([c.radius for c in circles], dtype=np.float64),
            np.array([c.sweep_rad for c in circles], dtype=np.float64))


def path_elements(curves: list[NurbsCurve] | tuple[NurbsCurve, ...],
                  sample_tolerance_mm: float = SAMPLE_TOLERANCE_MM) -> PathElements:
    """The elements (segments, arcs) of a sequence of curves (module docstring)."""
    collector = _Collector(sample_tolerance_mm)
    for curve in curves:
        collector.curve(curve)
    return collector.elements()


def program_path(program: Program, sample_tolerance_mm: float = SAMPLE_TOLERANCE_MM) -> PathElements:
    """Every block of the program, rapids included, in machine coordinates."""
    return path_elements([block.curve for block in program.blocks], sample_tolerance_mm)


# ---- exact distances ----------------------------------------------------------------------------------
def segment_distances(p: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    """Row-wise distance of points p to segments [a, b] (all (K, 3))."""
    d = b - a
    dd = np.einsum("ij,ij->i", d, d)
    t = np.einsum("ij,ij->i", p - a, d) / np.where(dd > 0, dd, 1.0)
    t = np.clip(np.where(dd > 0, t, 0.0), 0.0, 1.0)
    return np.linalg.norm(p - a - t[:, None] * d, axis=1)


def arc_distances(p: FloatArray, path: PathElements, index: NDArray[np.intp]) -> FloatArray:
    """Row-wise distance of points p to the arcs ``index`` of the path (module docstring)."""
    q = p - path.arc_center[index]
    u, v = path.arc_u[index], path.arc_v[index]
    x, y = np.einsum("ij,ij->i", q, u), np.einsum("ij,ij->i", q, v)
    z2 = np.maximum(np.einsum("ij,ij->i", q, q) - x * x - y * y, 0.0)
    rho = np.hypot(x, y)
    phi = np.mod(np.arctan2(y, x), 2.0 * np.pi)
    sweep = path.arc_sweep_rad[index]
    inside = np.sqrt(z2 + (rho - path.arc_radius[index]) ** 2)
    ends = np.minimum(np.linalg.norm(p - path.arc_start[index], axis=1), np.linalg.norm(p - path.arc_end[index], axis=1))
    return np.where(phi <= sweep, inside, ends)


def pair_distances(points: FloatArray, path: PathElements, point_index: NDArray[np.intp],
                   element: NDArray[np.intp]) -> FloatArray:
    """Distance of points[point_index[k]] to element[k] (< segment_count: a segment, else an arc)."""
    out = np.empty(len(element))
    seg = element < path.segment_count
    k = np.flatnonzero(seg)
    out[k] = segment_distances(points[point_index[k]], path.seg_start[element[k]], path.seg_end[element[k]])
    k = np.flatnonzero(~seg)
    out[k] = arc_distances(points[point_index[k]], path, element[k] - path.segment_count)
    return out


# ---- search --------------------------------------------------------------------------------------------
def element_pieces(path: PathElements, cell_mm: float) -> tuple[FloatArray, FloatArray, NDArray[np.intp]]:
    """Bounding boxes (low, high) of pieces at most cell_mm long, and the element of each piece.
    An arc piece of angle a and radius R is boxed by its chord's end points widened by its sag
    R (1 - cos(a / 2))."""
    lows, highs, owners = [], [], []
    if path.segment_count:
        length = np.linalg.norm(path.seg_end - path.seg_start, axis=1)
        counts = np.maximum(1, np.ceil(length / cell_mm).astype(np.intp))
        owner = np.repeat(np.arange(path.segment_count), counts)
        first = np.repeat(np.cumsum(counts) - counts, counts)
        k = (np.arange(len(owner)) - first).astype(np.float64)
        n = counts[owner].astype(np.float64)
        d = (path.seg_end - path.seg_start)[owner]
        a, b = path.seg_start[owner] + (k / n)[:, None] * d, path.seg_start[owner] + ((k + 1) / n)[:, None] * d
        lows.append(np.minimum(a, b))
        highs.append(np.maximum(a, b))
        owners.append(owner)
    if path.arc_count:
        length = path.arc_radius * path.arc_sweep_rad
        counts = np.maximum(1, np.ceil(length / cell_mm).astype(np.intp))
        arc = np.repeat(np.arange(path.arc_count), counts)
        first = np.repeat(np.cumsum(counts) - counts, counts)
        k = (np.arange(len(arc)) - first).astype(np.float64)
        step = path.arc_sweep_rad[arc] / counts[arc]
        radius = path.arc_radius[arc][:, None]
        ends = []
        for angle in (k * step, (k + 1) * step):
            ends.append(path.arc_center[arc] + radius * (np.cos(angle)[:, None] * path.arc_u[arc]
                                                         + np.sin(angle)[:, None] * path.arc_v[arc]))
        sag = (radius[:, 0] * (1.0 - np.cos(step / 2.0)))[:, None]
        lows.append(np.minimum(ends[0], ends[1]) - sag)
        highs.append(np.maximum(ends[0], ends[1]) + sag)
        owners.append(arc + path.segment_count)
    return np.concatenate(lows), np.concatenate(highs), np.concatenate(owners)


def cell_keys(cells: NDArray[np.int64]) -> NDArray[np.int64]:
    """One int64 per integer cell (ix, iy, iz), |i| < 2^20 (a 1 mm grid spans +-1 km)."""
    shifted = cells + (1 << 20)
    return (shifted[..., 0] << 42) | (shifted[..., 1] << 21) | shifted[..., 2]


@dataclass(frozen=True, eq=False)
class CellIndex:
    """Elements registered by grid cell: ``element[starts[i]:ends[i]]`` lie in cell ``keys[i]``."""

    cell_mm: float
    keys: NDArray[np.int64]
    element: NDArray[np.intp]

    @classmethod
    def build(cls, path: PathElements, cell_mm: float) -> CellIndex:
        low, high, owner = element_pieces(path, cell_mm)
        radius = 0.5 * cell_mm
        lo = np.floor((low - radius) / cell_mm).astype(np.int64)
        hi = np.floor((high + radius) / cell_mm).astype(np.int64)  # hi - lo <= 2: piece <= h, widened by h
        keys, elements = [], []
        for offset in np.stack(np.meshgrid([0, 1, 2], [0, 1, 2], [0, 1, 2], indexing="ij"), -1).reshape(-1, 3):
            cell = lo + offset
            ok = np.all(cell <= hi, axis=1)
            keys.append(cell_keys(cell[ok]))
            elements.append(owner[ok])
        key, element = np.concatenate(keys), np.concatenate(elements)
        pairs = np.unique(np.stack([key, element.astype(np.int64)], axis=1), axis=0)
        return cls(cell_mm, pairs[:, 0].copy(), pairs[:, 1].astype(np.intp))

    def candidates(self, points: FloatArray) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """(point index, element) pairs: the elements registered in each point's cell."""
        key = cell_keys(np.floor(points / self.cell_mm).astype(np.int64))
        lo = np.searchsorted(self.keys, key, side="left")
        counts = np.searchsorted(self.keys, key, side="right") - lo
        point = np.repeat(np.arange(len(points)), counts)
        first = np.repeat(np.cumsum(counts) - counts, counts)
        element = self.element[np.repeat(lo, counts) + np.arange(len(point)) - first]
        return point, element


def brute_distances(points: FloatArray, path: PathElements) -> FloatArray:
    """Distance of every point to its nearest element, trying them all (in bounded chunks)."""
    total = path.segment_count + path.arc_count
    out = np.full(len(points), np.inf)
    if total == 0:
        return out
    per_chunk = max(1, BRUTE_CHUNK_PAIRS // total)
    elements = np.arange(total)
    for start in range(0, len(points), per_chunk):
        idx = np.arange(start, min(start + per_chunk, len(points)))
        point = np.repeat(idx, total)
        d = pair_distances(points, path, point, np.tile(elements, len(idx)))
        out[idx] = d.reshape(len(idx), total).min(axis=1)
    return out


def nearest_in_cells(points: FloatArray, path: PathElements, cell_mm: float) -> FloatArray:
    """Distance to the nearest element registered in each point's cell (inf when none): exact
    wherever it is <= cell_mm / 2 (module docstring)."""
    out = np.full(len(points), np.inf)
    point, element = CellIndex.build(path, cell_mm).candidates(points)
    if len(point):  # pairs come grouped by point, in point order
        d = pair_distances(points, path, point, element)
        starts = np.flatnonzero(np.r_[True, point[1:] != point[:-1]])
        out[point[starts]] = np.minimum.reduceat(d, starts)
    return out


def distances_to_path(points: ArrayLike, path: PathElements, cell_mm: float = CELL_MM) -> FloatArray:
    """Distance of each point (N, 3) to the nearest point of the path (module docstring):
    grids of cell_mm, then CELL_GROWTH times coarser ones for the points farther than half a
    cell, then every element for those still farther."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.full(len(pts), np.inf)
    if len(pts) == 0 or path.segment_count + path.arc_count == 0:
        return out
    todo = np.arange(len(pts))
    for level in range(CELL_LEVELS):
        if not len(todo):
            return out
        h = cell_mm * CELL_GROWTH**level
        out[todo] = nearest_in_cells(pts[todo], path, h)
        todo = todo[~(out[todo] <= 0.5 * h)]
    if len(todo):
        out[todo] = brute_distances(pts[todo], path)
    return out


def max_deviation_mm(points: ArrayLike, program: Program, cell_mm: float = CELL_MM) -> float:
    """Largest distance of any point from the program's path."""
    d = distances_to_path(points, program_path(program), cell_mm)
    return float(d.max()) if len(d) else 0.0
