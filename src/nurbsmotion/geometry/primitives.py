"""Lines and circular arcs as exact NURBS, so the planner only ever sees NurbsCurve.

A circular arc of sweep theta <= 90 deg is exactly the rational quadratic Bezier with
control points P0, P1 (intersection of the end tangents), P2 and weights 1, cos(theta/2), 1
(Piegl & Tiller, algorithm A7.1). Longer arcs are split into equal segments of at most
90 deg joined with double knots.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from nurbsmotion.geometry.nurbs import NurbsCurve

FULL_TURN = 2.0 * math.pi


def line_curve(start: ArrayLike, end: ArrayLike) -> NurbsCurve:
    """A straight segment as a degree-1 NURBS on [0, 1] (constant parametric speed)."""
    return NurbsCurve.create(1, [start, end], [1.0, 1.0], [0.0, 0.0, 1.0, 1.0])


def arc_sweep_rad(start_angle: float, end_angle: float, clockwise: bool, full_circle_if_equal: bool = True) -> float:
    """Signed sweep from start to end angle: negative clockwise, in (-2 pi, 2 pi]."""
    sweep = (end_angle - start_angle) % FULL_TURN
    if clockwise:
        sweep = sweep - FULL_TURN if sweep > 0 else (-FULL_TURN if full_circle_if_equal else 0.0)
    elif sweep == 0 and full_circle_if_equal:
        sweep = FULL_TURN
    return sweep


def arc_curve(center: ArrayLike, start: ArrayLike, sweep_rad: float, normal: ArrayLike = (0.0, 0.0, 1.0)) -> NurbsCurve:
    """Circular arc around ``center`` from ``start``, turning ``sweep_rad`` about ``normal``.

    Positive sweep is counter-clockwise seen from the tip of the normal (right-hand rule).
    The radius is |start - center| measured in the plane normal to ``normal``; the start's
    offset along the normal is kept constant (no helix).
    """
    c = np.asarray(center, dtype=float)
    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n)
    radial = np.asarray(start, dtype=float) - c
    height = float(radial @ n)
    x_axis = radial - height * n
    radius = float(np.linalg.norm(x_axis))
    if radius <= 0 or abs(sweep_rad) <= 0:
        raise ValueError("arc needs a positive radius and a non-zero sweep")
    x_axis /= radius
    y_axis = np.cross(n, x_axis)
    origin = c + height * n
    segments = max(1, math.ceil(abs(sweep_rad) / (math.pi / 2) - 1e-9))
    delta = sweep_rad / segments
    w_mid = math.cos(delta / 2.0)

    def on_circle(angle: float, scale: float = 1.0) -> NDArray[np.float64]:
        return origin + scale * radius * (math.cos(angle) * x_axis + math.sin(angle) * y_axis)

    points = [on_circle(0.0)]
    weights = [1.0]
    for i in range(segments):
        a0 = i * delta
        points.append(on_circle(a0 + delta / 2.0, 1.0 / w_mid))  # tangent intersection
        points.append(on_circle(a0 + delta))
        weights += [w_mid, 1.0]
    inner = np.repeat(np.arange(1, segments) / segments, 2)
    knots = np.concatenate([[0.0, 0.0, 0.0], inner, [1.0, 1.0, 1.0]])
    return NurbsCurve.create(2, points, weights, knots)
