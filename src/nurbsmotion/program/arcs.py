"""G02/G03 circular arcs -> exact rational quadratic NURBS (geometry.primitives.arc_curve).

Planes (RS274/NGC): G17 = XY (offsets I J, normal +Z), G18 = ZX (offsets K I, normal +Y),
G19 = YZ (offsets J K, normal +X). G03 turns counter-clockwise seen from the tip of the
normal (positive sweep by the right-hand rule), G02 clockwise.

Centre: I J K are offsets from the start (always incremental). With R, the centre lies on
the perpendicular bisector of the chord at distance h = sqrt(R^2 - d^2/4): on the left of
the chord for a counter-clockwise arc with R > 0 (sweep <= 180 deg), on the right for
clockwise; R < 0 asks for the arc longer than 180 deg (the other centre).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.geometry import NurbsCurve
from nurbsmotion.geometry.primitives import arc_curve, arc_sweep_rad

RADIUS_TOLERANCE_MM = 0.002
RADIUS_TOLERANCE_REL = 0.001
HELIX_TOLERANCE_MM = 1e-6
SAME_POINT_MM = 1e-9


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
    def normal(self) -> NDArray[np.float64]:
        n = np.zeros(3)
        n[self.normal_axis] = 1.0
        return n


PLANES = {
    17: Plane("G17", (0, 1), 2, ("I", "J")),
    18: Plane("G18", (2, 0), 1, ("K", "I")),
    19: Plane("G19", (1, 2), 0, ("J", "K")),
}
AXIS_LETTERS = "XYZ"


def _in_plane(plane: Plane, v: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([v[plane.axes[0]], v[plane.axes[1]]])


def _angle(plane: Plane, v: NDArray[np.float64]) -> float:
    a, b = _in_plane(plane, v)
    return math.atan2(b, a)


def check_not_helical(plane: Plane, start: NDArray[np.float64], end: NDArray[np.float64]) -> None:
    axis = plane.normal_axis
    if abs(end[axis] - start[axis]) > HELIX_TOLERANCE_MM:
        letter = AXIS_LETTERS[axis]
        raise ArcError(f"unsupported: helical arc ({letter} changes in a {plane.code} arc)", letter)


def centre_from_radius(plane: Plane, start: NDArray[np.float64], end: NDArray[np.float64], radius_mm: float,
                       clockwise: bool, radius_word: str) -> NDArray[np.float64]:
    """Centre of the R-format arc (module docstring), in the start's plane."""
    chord = _in_plane(plane, end - start)
    d = float(np.hypot(*chord))
    if d <= SAME_POINT_MM:
        raise ArcError("an R arc needs an end point different from the start (use I J K for a full circle)", radius_word)
    if radius_mm == 0:
        raise ArcError("arc radius must not be zero", radius_word)
    r = abs(radius_mm)
    excess = d / 2 - r
    if excess > max(RADIUS_TOLERANCE_MM, RADIUS_TOLERANCE_REL * r):
        raise ArcError(f"radius {r:g} mm is too small for the chord of {d:.6g} mm between start and end", radius_word)
    h = math.sqrt(max(r * r - d * d / 4, 0.0))
    left = np.array([-chord[1], chord[0]]) / d
    side = (1.0 if not clockwise else -1.0) * (1.0 if radius_mm > 0 else -1.0)
    mid = _in_plane(plane, start) + chord / 2
    centre_2d = mid + side * h * left
    centre = start.copy()
    centre[plane.axes[0]], centre[plane.axes[1]] = centre_2d
    return centre


def arc_nurbs(plane: Plane, start: NDArray[np.float64], end: NDArray[np.float64], centre: NDArray[np.float64],
              clockwise: bool, full_circle_if_closed: bool) -> NurbsCurve:
    """Exact arc from start to end about centre; radii must agree within tolerance.

    When the two radii differ (within tolerance) the centre is moved onto the chord's
    perpendicular bisector so the arc passes exactly through both programmed points.
    """
    check_not_helical(plane, start, end)
    r_start = float(np.hypot(*_in_plane(plane, start - centre)))
    r_end = float(np.hypot(*_in_plane(plane, end - centre)))
    if r_start <= SAME_POINT_MM:
        raise ArcError("arc radius is zero (the centre is at the start point)")
    if abs(r_start - r_end) > max(RADIUS_TOLERANCE_MM, RADIUS_TOLERANCE_REL * r_start):
        raise ArcError(f"inconsistent arc radius: {r_start:.6g} mm at the start, {r_end:.6g} mm at the end")
    closed = float(np.hypot(*_in_plane(plane, end - start))) <= SAME_POINT_MM
    if closed and not full_circle_if_closed:
        raise ArcError("arc end equals its start")
    if not closed and r_start != r_end:
        ccw_of_chord = _cross2(_in_plane(plane, end - start), _in_plane(plane, centre - start)) > 0
        radius = (r_start + r_end) / 2
        signed = radius if ccw_of_chord == (not clockwise) else -radius
        centre = centre_from_radius(plane, start, end, signed, clockwise, "")
    sweep = arc_sweep_rad(_angle(plane, start - centre), _angle(plane, end - centre), clockwise, closed)
    if closed:
        sweep = -2 * math.pi if clockwise else 2 * math.pi
    if sweep == 0:
        raise ArcError("arc end equals its start")
    curve = arc_curve(centre, start, sweep, plane.normal)
    points = curve.control_points.copy()
    points[0], points[-1] = start, (start if closed else end)  # exact programmed end points
    points.setflags(write=False)
    return dataclasses.replace(curve, control_points=points)  # moved by rounding only: still valid


def _cross2(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    return float(a[0] * b[1] - a[1] * b[0])
