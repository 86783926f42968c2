"""G02/G03 circular arcs -> ArcShape, whose curve is the exact rational quadratic NURBS
(geometry.primitives.arc_curve).

Planes (RS274/NGC): G17 = XY (offsets I J, normal +Z), G18 = ZX (offsets K I, normal +Y),
G19 = YZ (offsets J K, normal +X). G03 turns counter-clockwise seen from the tip of the
normal (positive sweep by the right-hand rule), G02 clockwise.

Centre: I J K are offsets from the start (always incremental). With R, the centre lies on
the perpendicular bisector of the chord at distance h = sqrt(R^2 - d^2/4): on the left of
the chord for a counter-clockwise arc with R > 0 (sweep <= 180 deg), on the right for
clockwise; R < 0 asks for the arc longer than 180 deg (the other centre).

Helical arcs: the normal axis may change between start and end (G17 with Z): the arc is
then a helix rising linearly with the angle (geometry.primitives.arc_curve). ``turns``
(LinuxCNC's P word) adds full turns.

Radius tolerances are LinuxCNC's (src/emc/rs274ngc/interp_internal.hh, interp_arc.cc):
centre format: the radii at start and end may differ by ``abs_err``; an error when
abs_err > 100 tol or (abs_err > tol and abs_err / r > 0.001), with tol = 2 sqrt(2) 0.001 in
(G20) or 2 sqrt(2) 0.01 mm (G21): any arc whose numbers were rounded to 0.001 in or 0.01 mm
is accepted. R format: R may be short of half the chord by 0.00005 in (0.00127 mm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.geometry.primitives import ArcShape, arc_sweep_rad

MM_PER_INCH = 25.4
CENTRE_TOLERANCE_MM = {False: 2 * math.sqrt(2) * 0.01, True: 2 * math.sqrt(2) * 0.001 * MM_PER_INCH}  # by inch units
CENTRE_TOLERANCE_REL = 0.001
CENTRE_TOLERANCE_CAP = 100.0  # abs_err above cap * tol is always an error
R_TOLERANCE_MM = 0.00005 * MM_PER_INCH
SAME_POINT_MM = 1e-9

Point = Sequence[float]  # X Y Z in mm (a tuple, or an ndarray of 3)


class ArcError(ValueError):
    """A bad arc; ``word`` is the G-code word to blame (e.g. 'R5', 'Z'), if any."""

    def __init__(self, message: str, word: str = "") -> None:
        self.word = word
        super().__init__(message)


@dataclass(frozen=True)
class Plane:
    code: str  # G17 | G18 | G19
    axes: tuple[int, int]  # indices of the two plane axes (first, second) in XYZ
    normal_axis: int
    offset_letters: tuple[str, str]  # centre offset words for the two plane axes

    @property
    def normal(self) -> tuple[float, float, float]:
        n = [0.0, 0.0, 0.0]
        n[self.normal_axis] = 1.0
        return n[0], n[1], n[2]


PLANES = {
    17: Plane("G17", (0, 1), 2, ("I", "J")),
    18: Plane("G18", (2, 0), 1, ("K", "I")),
    19: Plane("G19", (1, 2), 0, ("J", "K")),
}
AXIS_LETTERS = "XYZ"


def _hypot(a: float, b: float) -> float:
    """sqrt(a^2 + b^2) by the C library's hypot (numpy's). Python's math.hypot rounds
    differently in about 1 case in 700, and the radii at start and end are compared for
    equality (arc_nurbs): the same function keeps every arc's geometry as it was."""
    return float(np.hypot(a, b))


def _in_plane(plane: Plane, frm: Point, to: Point) -> tuple[float, float]:
    """The plane components of the vector ``to - frm``."""
    a, b = plane.axes
    return to[a] - frm[a], to[b] - frm[b]


def _angle(plane: Plane, centre: Point, point: Point) -> float:
    a, b = _in_plane(plane, centre, point)
    return math.atan2(b, a)


def radii_agree(r_start: float, r_end: float, inch: bool) -> bool:
    """LinuxCNC's centre-format rule (module docstring)."""
    tol = CENTRE_TOLERANCE_MM[inch]
    abs_err = abs(r_start - r_end)
    rel_err = abs_err / max(r_start, r_end)
    return not (abs_err > CENTRE_TOLERANCE_CAP * tol or (rel_err > CENTRE_TOLERANCE_REL and abs_err > tol))


def checked_r_radius(chord_mm: float, radius_mm: float, radius_word: str) -> float:
    """|R| of an R-format arc over a chord of ``chord_mm``; ArcError (blaming ``radius_word``)
    for a zero chord, a zero radius or a radius short of half the chord beyond R_TOLERANCE_MM."""
    if chord_mm <= SAME_POINT_MM:
        raise ArcError("an R arc needs an end point different from the start (use I J K for a full circle)", radius_word)
    if radius_mm == 0:
        raise ArcError("arc radius must not be zero", radius_word)
    r = abs(radius_mm)
    if chord_mm / 2 - r > R_TOLERANCE_MM:
        raise ArcError(f"radius {r:g} mm is too small for the chord of {chord_mm:.6g} mm between start and end",
                       radius_word)
    return r


def check_radii(r_start: float, r_end: float, inch: bool) -> None:
    """ArcError for a centre at the start point or radii at start and end that disagree (radii_agree)."""
    if r_start <= SAME_POINT_MM:
        raise ArcError("arc radius is zero (the centre is at the start point)")
    if not radii_agree(r_start, r_end, inch):
        raise ArcError(f"inconsistent arc radius: {r_start:.6g} mm at the start, {r_end:.6g} mm at the end "
                       f"(LinuxCNC's tolerance: {CENTRE_TOLERANCE_MM[inch]:.4g} mm, or {CENTRE_TOLERANCE_REL:g} of the radius)")


def centre_from_radius(plane: Plane, start: Point, end: Point, radius_mm: float,
                       clockwise: bool, radius_word: str, chord_mm: float | None = None) -> tuple[float, float, float]:
    """Centre of the R-format arc (module docstring), in the start's plane (``chord_mm``: the
    chord's length in the plane, when the caller has it)."""
    chord_a, chord_b = _in_plane(plane, start, end)
    d = _hypot(chord_a, chord_b) if chord_mm is None else chord_mm
    r = checked_r_radius(d, radius_mm, radius_word)
    h = math.sqrt(max(r * r - d * d / 4, 0.0))
    side = (1.0 if not clockwise else -1.0) * (1.0 if radius_mm > 0 else -1.0)
    a, b = plane.axes
    offset = side * h  # along the chord's left normal (-chord_b, chord_a) / d
    centre = [float(start[0]), float(start[1]), float(start[2])]
    centre[a] = (start[a] + chord_a / 2) + offset * (-chord_b / d)
    centre[b] = (start[b] + chord_b / 2) + offset * (chord_a / d)
    return centre[0], centre[1], centre[2]


def arc_nurbs(plane: Plane, start: Point, end: Point, centre: Point,
              clockwise: bool, full_circle_if_closed: bool, inch: bool = False, turns: int = 1) -> NurbsCurve:
    """Exact arc (or helix) from start to end about centre as a NURBS (arc_shape's curve)."""
    return arc_shape(plane, start, end, centre, clockwise, full_circle_if_closed, inch, turns).curve()


def arc_shape(plane: Plane, start: Point, end: Point, centre: Point,
              clockwise: bool, full_circle_if_closed: bool, inch: bool = False, turns: int = 1) -> ArcShape:
    """Exact arc (or helix) from start to end about centre; radii must agree within tolerance.

    When the two radii differ (within tolerance) the centre is moved onto the chord's
    perpendicular bisector so the arc passes exactly through both programmed points.
    Plain floats throughout (geometry.primitives.arc_curve says why).
    """
    r_start = _hypot(*_in_plane(plane, centre, start))
    r_end = _hypot(*_in_plane(plane, centre, end))
    chord_mm = _hypot(*_in_plane(plane, start, end))
    centre, sweep, rise = arc_geometry(plane, start, end, centre, clockwise, full_circle_if_closed, inch, turns,
                                       (r_start, r_end, chord_mm))
    return ArcShape(_point(start), _point(end), _point(centre), sweep, plane.normal, rise)  # exact programmed end points


def arc_geometry(plane: Plane, start: Point, end: Point, centre: Point, clockwise: bool, full_circle_if_closed: bool,
                 inch: bool, turns: int, lengths_mm: tuple[float, float, float]) -> tuple[Point, float, float]:
    """arc_shape's numbers: (centre, sweep in rad, rise in mm), given ``lengths_mm`` = (radius at
    the start, radius at the end, chord), each measured in the plane by _hypot; ArcError."""
    r_start, r_end, chord_mm = lengths_mm
    check_radii(r_start, r_end, inch)
    chord = _in_plane(plane, start, end)
    closed = chord_mm <= SAME_POINT_MM
    if closed and not full_circle_if_closed:
        raise ArcError("arc end equals its start")
    if not closed and r_start != r_end:
        ccw_of_chord = _cross2(chord, _in_plane(plane, start, centre)) > 0
        radius = (r_start + r_end) / 2
        signed = radius if ccw_of_chord == (not clockwise) else -radius
        centre = centre_from_radius(plane, start, end, signed, clockwise, "", chord_mm)
    sweep = arc_sweep_rad(_angle(plane, centre, start), _angle(plane, centre, end), clockwise, closed)
    if closed:
        sweep = -2 * math.pi if clockwise else 2 * math.pi
    if sweep == 0:
        raise ArcError("arc end equals its start")
    sweep += math.copysign(2 * math.pi * (turns - 1), sweep)
    return centre, sweep, float(end[plane.normal_axis] - start[plane.normal_axis])


def arc_lengths_in_plane(plane: Plane, starts: np.ndarray, ends: np.ndarray,
                         centres: np.ndarray) -> list[tuple[float, float, float]]:
    """arc_geometry's ``lengths_mm`` of many arcs (rows (m, 3)) at once: numpy's hypot (the
    same C function _hypot calls) over the columns, one call per length instead of one per arc."""
    a, b = plane.axes
    r_start = np.hypot(starts[:, a] - centres[:, a], starts[:, b] - centres[:, b])
    r_end = np.hypot(ends[:, a] - centres[:, a], ends[:, b] - centres[:, b])
    chord = np.hypot(ends[:, a] - starts[:, a], ends[:, b] - starts[:, b])
    return list(zip(r_start.tolist(), r_end.tolist(), chord.tolist()))


def _point(p: Point) -> np.ndarray:
    return np.array([float(p[0]), float(p[1]), float(p[2])])


def _cross2(a: tuple[float, float], b: tuple[float, float]) -> float:
    return a[0] * b[1] - a[1] * b[0]
