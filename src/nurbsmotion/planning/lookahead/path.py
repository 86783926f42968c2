"""The path of a run of blocks as one arc-length grid with its differential geometry.

Each block is sampled on a grid in u, fine where the path turns (at most
``MAX_TURN_RAD`` of tangent turn per interval) and at most ``spacing_mm`` apart; the arc
length of every interval comes from 5-point Gauss-Legendre. At every grid point we keep the
arc-length derivatives of the path (reference §1 derivatives, chain rule with sigma = |x'|):

  t = x_s = x' / sigma,   c = x_ss = (x'' sigma - x' sigma') / sigma^3,
  x_sss = N' / sigma^4 - 3 N sigma' / sigma^5,  N = x'' sigma - x' sigma',
  N' = x''' sigma - x' sigma'',  sigma' = t.x'',  sigma'' = (|x''|^2 + x'.x''' - sigma'^2) / sigma

and du/ds = 1/sigma, d2u/ds2 = -sigma' / sigma^3 for the s -> u table. A block junction is
two grid points at the same s (one per block), so every interval lies inside one block.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from nurbsmotion.geometry import NurbsCurve

MAX_TURN_RAD = 0.02  # tangent turn per grid interval
COARSE_PER_SPAN = 32  # first look at each knot span
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(5)
TINY_SPEED = 1e-300


@dataclass(frozen=True, eq=False)
class BlockPiece:
    """Part [u_start, u_end] of one program block inside a planning window."""

    block: int
    curve: NurbsCurve
    u_start: float
    u_end: float
    feed_mm_s: float


@dataclass(eq=False)
class PathGrid:
    """Grid over a run of block pieces; s starts at 0 at the first piece's start."""

    s: NDArray[np.float64]  # (N,) arc length, non-decreasing (junctions repeat s)
    piece: NDArray[np.int32]  # (N,) index into ``pieces``
    u: NDArray[np.float64]  # (N,)
    u_s: NDArray[np.float64]  # (N,) du/ds
    u_ss: NDArray[np.float64]  # (N,) d2u/ds2
    tangent: NDArray[np.float64]  # (N, 3) x_s
    curv: NDArray[np.float64]  # (N, 3) x_ss (curvature vector)
    dcurv: NDArray[np.float64]  # (N, 3) x_sss
    feed_mm_s: NDArray[np.float64]  # (N,) programmed feed of the point's block
    position: NDArray[np.float64]  # (N, 3) x
    pieces: tuple[BlockPiece, ...]

    def __len__(self) -> int:
        return len(self.s)

    @property
    def length_mm(self) -> float:
        return float(self.s[-1])

    @property
    def junction(self) -> NDArray[np.bool_]:
        """(N-1,) True for the zero-length intervals between two pieces."""
        return self.piece[1:] != self.piece[:-1]


def coarse_lengths(curve: NurbsCurve, u_start: float, u_end: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(u, approximate arc length from u_start) on a coarse polyline (COARSE_PER_SPAN points per
    knot span): enough to size look-ahead windows, without the curve's exact quadrature."""
    knots = curve.breakpoints
    edges = np.concatenate([[u_start], knots[(knots > u_start) & (knots < u_end)], [u_end]])
    frac = np.linspace(0.0, 1.0, COARSE_PER_SPAN + 1)[:-1]
    u = np.append((edges[:-1, None] + (edges[1:] - edges[:-1])[:, None] * frac[None, :]).ravel(), u_end)
    x = curve.points(u)
    return u, np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(x, axis=0), axis=1))])


def gauss_lengths(curve: NurbsCurve, u0: NDArray[np.float64], u1: NDArray[np.float64]) -> NDArray[np.float64]:
    """Arc length of each [u0, u1] by 5-point Gauss-Legendre (intervals are short)."""
    half = (u1 - u0) / 2.0
    u = ((u0 + u1) / 2.0)[:, None] + half[:, None] * _GL_NODES[None, :]
    speed = np.linalg.norm(curve.derivatives(u.ravel(), 1)[1], axis=1).reshape(u.shape)
    return (speed * _GL_WEIGHTS[None, :]).sum(axis=1) * half


def piece_u_grid(piece: BlockPiece, spacing_mm: float) -> NDArray[np.float64]:
    """u values of the grid of one piece: each coarse interval split so that it is at most
    ``spacing_mm`` long and turns at most MAX_TURN_RAD."""
    curve = piece.curve
    knots = curve.breakpoints
    inner = knots[(knots > piece.u_start) & (knots < piece.u_end)]
    edges = np.concatenate([[piece.u_start], inner, [piece.u_end]])
    per_span = 2 if curve.degree == 1 else COARSE_PER_SPAN
    frac = np.linspace(0.0, 1.0, per_span + 1)[:-1]
    coarse = np.append((edges[:-1, None] + (edges[1:] - edges[:-1])[:, None] * frac[None, :]).ravel(), edges[-1])
    d = curve.derivatives(coarse, 1)[1]
    speed = np.linalg.norm(d, axis=1)
    t = d / np.maximum(speed, TINY_SPEED)[:, None]
    du = np.diff(coarse)
    length = 0.5 * (speed[1:] + speed[:-1]) * du
    turn = np.arccos(np.clip(np.einsum("ij,ij->i", t[1:], t[:-1]), -1.0, 1.0))
    count = np.maximum(np.ceil(np.maximum(length / spacing_mm, turn / MAX_TURN_RAD)), 1).astype(np.int64)
    starts = np.repeat(coarse[:-1], count)
    offsets = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    fine = starts + np.repeat(du / count, count) * offsets
    return np.append(fine, coarse[-1])


def arc_length_derivatives(curve: NurbsCurve, u: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    """(x, x_s, x_ss, x_sss, du/ds, d2u/ds2) at each u (module docstring)."""
    x, d1, d2, d3 = curve.derivatives(u, 3)
    sigma = np.maximum(np.linalg.norm(d1, axis=1), TINY_SPEED)
    t = d1 / sigma[:, None]
    sigma1 = np.einsum("ij,ij->i", t, d2)
    sigma2 = (np.einsum("ij,ij->i", d2, d2) + np.einsum("ij,ij->i", d1, d3) - sigma1**2) / sigma
    n = d2 * sigma[:, None] - d1 * sigma1[:, None]
    n1 = d3 * sigma[:, None] - d1 * sigma2[:, None]
    curv = n / sigma[:, None] ** 3
    dcurv = n1 / sigma[:, None] ** 4 - 3.0 * n * (sigma1 / sigma**5)[:, None]
    return x, t, curv, dcurv, 1.0 / sigma, -sigma1 / sigma**3


def to_3d(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pad (N, dim<3) arrays to 3 columns (planning is in XYZ)."""
    if a.shape[1] == 3:
        return a
    out = np.zeros((len(a), 3))
    out[:, : min(3, a.shape[1])] = a[:, :3]
    return out


def build_grid(pieces: tuple[BlockPiece, ...], spacing_mm: float) -> PathGrid:
    """The grid of a run of pieces (consecutive pieces meet at their ends)."""
    parts: dict[str, list] = {k: [] for k in ("s", "piece", "u", "u_s", "u_ss", "tangent", "curv", "dcurv", "feed", "position")}
    offset = 0.0
    for index, piece in enumerate(pieces):
        u = piece_u_grid(piece, spacing_mm)
        ds = gauss_lengths(piece.curve, u[:-1], u[1:])
        s = offset + np.concatenate([[0.0], np.cumsum(ds)])
        x, t, curv, dcurv, u_s, u_ss = arc_length_derivatives(piece.curve, u)
        for key, value in (("s", s), ("u", u), ("u_s", u_s), ("u_ss", u_ss), ("tangent", to_3d(t)),
                           ("curv", to_3d(curv)), ("dcurv", to_3d(dcurv)), ("position", to_3d(x))):
            parts[key].append(value)
        parts["piece"].append(np.full(len(u), index, dtype=np.int32))
        parts["feed"].append(np.full(len(u), piece.feed_mm_s))
        offset = float(s[-1])
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    return PathGrid(s=cat["s"], piece=cat["piece"], u=cat["u"], u_s=cat["u_s"], u_ss=cat["u_ss"],
                    tangent=cat["tangent"], curv=cat["curv"], dcurv=cat["dcurv"], feed_mm_s=cat["feed"], position=cat["position"],
                    pieces=tuple(pieces))
