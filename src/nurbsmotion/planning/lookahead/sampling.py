"""Exact sampling: the parameter u of every set-point from its planned arc length.

On grid interval k (s_k..s_k+1) u(s) is first the quintic Hermite interpolant of u, du/ds
and d2u/ds2 at both ends; then Newton corrections on the arc length,
  s(u) = s_k + h integral_0^r p(r') dr'   (p the interval's speed polynomial, path.py),
  u <- u - (s(u) - s*) / p(r),
until |s(u) - s*| <= ARC_TOLERANCE_SHARE x the shorter of the set-point's two steps (or
ARC_TOLERANCE_FLOOR_MM at rest; at most NEWTON_STEPS): 1 % of the fluctuation limit, so
the check (difference of two residuals over the step) passes. The final residual of every
set-point is kept: the arc length of a step differs from its planned length by exactly
the difference of the residuals at its ends, which is what the verification checks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.planning.lookahead.path import TINY_SPEED, PathGrid, to_3d
from nurbsmotion.planning.lookahead.search import search_sorted

ARC_TOLERANCE_SHARE = 1e-8
ARC_TOLERANCE_FLOOR_MM = 1e-13
NEWTON_STEPS = 4


@dataclass(eq=False)
class Samples:
    """Set-points of one stretch of a plan."""

    piece: NDArray[np.int32]
    u: NDArray[np.float64]
    position_mm: NDArray[np.float64]
    arc_residual_mm: NDArray[np.float64] | None = None  # s(u) - planned s of every set-point


def hermite_u(grid: PathGrid, k: NDArray[np.intp], s: NDArray[np.float64]) -> NDArray[np.float64]:
    """Quintic Hermite interpolation of u(s) on grid interval k (PathGrid.u_of_s_poly, Horner);
    exactly u_k and u_k+1 at the interval's ends (a block's end point is its last control
    point only when u is exactly its end)."""
    h = grid.interval_mm.take(k)
    r = (s - grid.s.take(k)) / np.where(h > 0, h, 1.0)
    np.clip(r, 0.0, 1.0, out=r)
    c = grid.u_of_s_poly.take(k, axis=1)  # one gather of all coefficients
    u = c[5]
    for j in range(4, -1, -1):
        u *= r
        u += c[j]
    end = np.flatnonzero(r == 1.0)
    u[end] = grid.u[k[end] + 1]
    return u


def grid_interval(grid: PathGrid, s: NDArray[np.float64]) -> NDArray[np.intp]:
    """Interval k with s_k <= s < s_k+1; at a junction the interval of the later piece."""
    k = np.clip(search_sorted(grid.s, s, side="right") - 1, 0, len(grid) - 2)
    # a zero-length (junction) interval at the very end of the grid: step back into the piece
    while True:
        zero = grid.interval_mm.take(k) <= 0.0  # s_k+1 <= s_k
        if not zero.any():
            return k
        k = np.where(zero, k - 1, k)


def interval_fraction(grid: PathGrid, k: NDArray[np.intp], u: NDArray[np.float64]) -> NDArray[np.float64]:
    """Where u lies on interval k: r = (u - u_k) / h, h the interval's width in u (1 where 0)."""
    return (u - grid.u.take(k)) / grid.interval_u_nonzero.take(k)


def arc_residuals(grid: PathGrid, k: NDArray[np.intp], s: NDArray[np.float64], u: NDArray[np.float64]) -> NDArray[np.float64]:
    """s(u) - s* with s(u) = s_k + h integral_0^r p (Horner on p's coefficients / (j + 1))."""
    r, h = interval_fraction(grid, k, u), grid.interval_u.take(k)
    coeffs = grid.speed_integral_poly.take(k, axis=1)  # one gather of all coefficients
    integral = coeffs[-1]
    for j in range(len(coeffs) - 2, -1, -1):
        integral = integral * r + coeffs[j]
    return grid.s.take(k) + integral * r * h - s


def interval_speeds(grid: PathGrid, k: NDArray[np.intp], u: NDArray[np.float64]) -> NDArray[np.float64]:
    """|x'(u)| from the interval's speed polynomial."""
    r = interval_fraction(grid, k, u)
    coeffs = grid.speed_poly.take(k, axis=1)  # one gather of all coefficients
    speed = coeffs[-1]
    for j in range(len(coeffs) - 2, -1, -1):
        speed = speed * r + coeffs[j]
    return speed


def arc_tolerances(s: NDArray[np.float64]) -> NDArray[np.float64]:
    """Newton's tolerance at every set-point: ARC_TOLERANCE_SHARE x its shorter adjacent step."""
    step = np.abs(np.diff(s))
    if len(step) == 0:
        return np.full(len(s), ARC_TOLERANCE_FLOOR_MM)
    shorter = np.minimum(np.concatenate([step[:1], step]), np.concatenate([step, step[-1:]]))
    return np.maximum(ARC_TOLERANCE_SHARE * shorter, ARC_TOLERANCE_FLOOR_MM)


def piece_runs(pieces: NDArray[np.int32]) -> list[tuple[int, slice]]:
    """(piece, slice) of every run of equal piece numbers (set-points follow the path, so each
    piece's set-points are one run)."""
    edges = np.concatenate([[0], np.flatnonzero(pieces[1:] != pieces[:-1]) + 1, [len(pieces)]])
    return [(int(pieces[a]), slice(int(a), int(b))) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def newton_on_arc_length(grid: PathGrid, k: NDArray[np.intp], s: NDArray[np.float64],
                         u: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Newton corrections of u on the arc length (module docstring). Returns u and the final
    residual s(u) - s* of every point (the measured arc error)."""
    u = u.copy()
    tolerance = arc_tolerances(s)
    err = arc_residuals(grid, k, s, u)
    for _ in range(NEWTON_STEPS):
        todo = np.flatnonzero(np.abs(err) > tolerance)
        if len(todo) == 0:
            break
        kt = k[todo]
        speed = interval_speeds(grid, kt, u[todo])
        u[todo] = np.clip(u[todo] - err[todo] / np.maximum(speed, TINY_SPEED), grid.u[kt], grid.u[kt + 1])
        err[todo] = arc_residuals(grid, kt, s[todo], u[todo])
    return u, err


def sample_path(grid: PathGrid, s: NDArray[np.float64]) -> Samples:
    """Set-points at arc lengths ``s`` (non-decreasing) of the grid's path."""
    k = grid_interval(grid, s)
    u, residual = newton_on_arc_length(grid, k, s, hermite_u(grid, k, s))
    pieces = grid.piece[k]
    position = np.empty((len(s), 3))
    for p, sel in piece_runs(pieces):
        curve = grid.pieces[p].curve
        here = position[sel]
        x = curve.derivatives_by_coordinate(u[sel], 0)[0]  # (dim, n): one transposed copy into place
        axes = min(curve.dim, 3)
        here[:, :axes] = x[:axes].T
        here[:, axes:] = 0.0
        # a block's ends are its first and last control points exactly (clamped knots)
        here[u[sel] == curve.u_max] = to_3d(curve.control_points[-1:])[0]
        here[u[sel] == curve.u_min] = to_3d(curve.control_points[:1])[0]
    return Samples(piece=pieces.astype(np.int32), u=u, position_mm=position, arc_residual_mm=residual)
