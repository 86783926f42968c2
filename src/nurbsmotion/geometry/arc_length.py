"""Arc length of a NURBS curve: the speed |x'(u)| as a polynomial per knot span, its integral
s(u) by adaptive Gauss-Legendre quadrature, and the inverse u(s) by safeguarded Newton.

On a span with left knot u_s, A = [C, W] is the polynomial sum_k c_k t^k (t = u - u_s, the
curve's Taylor coefficients), and x' = N / W^2 with N = C' W - C W' (degree <= 2p - 2), so
|x'(u)| = |N(u)| / W(u)^2 takes two Horner schemes.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

_GAUSS_16 = np.polynomial.legendre.leggauss(16)


class ArcLength:
    """|x'(u)|, s(u) and u(s) of one curve (NurbsCurve.speeds, .length, .arc_length,
    .u_at_arc_length), from its Taylor coefficients per span."""

    def __init__(self, lefts: NDArray[np.float64], coeffs: NDArray[np.float64], degree: int,
                 breakpoints: NDArray[np.float64], chunk: int) -> None:
        self.lefts = lefts  # the left knot of every non-empty span
        self.coeffs = coeffs  # c[k, :, i] = A^(k)(lefts[i]) / k!, shape (p+1, dim+1, spans)
        self.degree = degree
        self.dim = int(coeffs.shape[1]) - 1
        self.breakpoints = breakpoints  # distinct knot values
        self.u_min, self.u_max = float(breakpoints[0]), float(breakpoints[-1])
        self.chunk = chunk  # points per block of work (nurbs.EVALUATION_CHUNK)

    @cached_property
    def speed_polynomials(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Per span, the Taylor coefficients of N = C' W - C W' (the numerator of x' = N / W^2,
        degree <= 2p - 2) and of W: arrays (2p - 1, dim, spans) and (p + 1, spans)."""
        coeffs = self.coeffs
        p = self.degree
        c, w = coeffs[:, :-1, :], coeffs[:, -1, :]
        numerator = np.zeros((2 * p + 1, self.dim, c.shape[2]))
        for a in range(p + 1):
            for b in range(p + 1):
                # d/dt of c_a t^a times w_b t^b minus c_a t^a times d/dt of w_b t^b (0 for a = b)
                if a != b:
                    numerator[a + b - 1] += (a - b) * c[a] * w[b]
        return np.ascontiguousarray(numerator[: max(2 * p - 1, 1)]), np.ascontiguousarray(w)

    def speeds(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """|x'(u)| for an array of u (the integrand of the arc length): |N(u)| / W(u)^2 with
        N = C' W - C W' by Horner's scheme on the span's coefficients."""
        uu = np.asarray(u, dtype=np.float64)
        lefts = self.lefts
        numerator, weight = self.speed_polynomials
        out = np.empty(len(uu))
        for start in range(0, len(uu), self.chunk):
            chunk = uu[start: start + self.chunk]
            i = np.clip(np.searchsorted(lefts, chunk, side="right") - 1, 0, len(lefts) - 1)
            t = chunk - lefts.take(i)
            n_c = numerator.take(i, axis=2)
            w_c = weight.take(i, axis=1)
            n = n_c[-1]
            for j in range(len(n_c) - 2, -1, -1):
                n = n * t + n_c[j]
            w = w_c[-1]
            for j in range(len(w_c) - 2, -1, -1):
                w = w * t + w_c[j]
            out[start: start + len(chunk)] = np.sqrt(np.einsum("ij,ij->j", n, n)) / (w * w)
        return out

    def gauss_integrals(self, starts: NDArray[np.float64], ends: NDArray[np.float64]) -> NDArray[np.float64]:
        """Integral of |x'(u)| over each [start, end] by 16-point Gauss-Legendre."""
        nodes, weights = _GAUSS_16
        half = (ends - starts) / 2.0
        u = (starts + ends)[:, None] / 2.0 + half[:, None] * nodes[None, :]
        return (self.speeds(u.ravel()).reshape(u.shape) @ weights) * half

    @cached_property
    def quadrature(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Adaptive Gauss-Legendre: (interval edges, cumulative length at each edge).

        Each knot span starts as 4 intervals; an interval is halved until the rule on it and
        on its two halves agree to 1e-13 of the total length (at most 20 halvings).
        """
        edges = np.unique(np.concatenate([np.linspace(a, b, 5) for a, b in zip(self.breakpoints[:-1], self.breakpoints[1:])]))
        starts, ends = edges[:-1], edges[1:]
        whole = self.gauss_integrals(starts, ends)
        done_starts, done_ends, done_values = [], [], []
        tolerance = 1e-13 * max(whole.sum(), 1e-300)
        for _ in range(20):
            mids = (starts + ends) / 2.0
            left, right = self.gauss_integrals(starts, mids), self.gauss_integrals(mids, ends)
            ok = np.abs(left + right - whole) <= tolerance
            done_starts += [starts[ok], mids[ok]]
            done_ends += [mids[ok], ends[ok]]
            done_values += [left[ok], right[ok]]
            if ok.all():
                break
            bad = ~ok
            starts, ends = np.concatenate([starts[bad], mids[bad]]), np.concatenate([mids[bad], ends[bad]])
            whole = np.concatenate([left[bad], right[bad]])
        else:
            done_starts.append(starts)
            done_ends.append(ends)
            done_values.append(whole)
        all_starts = np.concatenate(done_starts)
        order = np.argsort(all_starts)
        values = np.concatenate(done_values)[order]
        edges = np.append(all_starts[order], self.u_max)
        return edges, np.concatenate([[0.0], np.cumsum(values)])

    @cached_property
    def cumulative_length(self) -> NDArray[np.float64]:
        return self.quadrature[1]

    @property
    def length(self) -> float:
        """Total arc length (adaptive 16-point Gauss-Legendre on each knot span)."""
        return float(self.cumulative_length[-1])

    def arc_length(self, u: ArrayLike) -> NDArray[np.float64] | float:
        """Arc length from u_min to u (vectorised)."""
        uu = np.clip(np.atleast_1d(np.asarray(u, dtype=np.float64)), self.u_min, self.u_max)
        edges, cumulative = self.quadrature
        idx = np.clip(np.searchsorted(edges, uu, side="right") - 1, 0, len(edges) - 2)
        s = cumulative[idx] + self.gauss_integrals(edges[idx], uu)
        return float(s[0]) if np.ndim(u) == 0 else s

    def u_at_arc_length(self, s: ArrayLike, tolerance_mm: float = 1e-10, max_iterations: int = 50) -> NDArray[np.float64] | float:
        """The parameter u with arc_length(u) = s: Newton on s(u) - s* safeguarded by bisection.

        The bracket starts as the quadrature sub-interval that holds s*, and every Newton
        step that leaves the bracket is replaced by its midpoint.
        """
        target = np.clip(np.atleast_1d(np.asarray(s, dtype=np.float64)), 0.0, self.length)
        edges, cum = self.quadrature
        idx = np.clip(np.searchsorted(cum, target, side="right") - 1, 0, len(edges) - 2)
        lo, hi = edges[idx].copy(), edges[idx + 1].copy()
        frac = np.divide(target - cum[idx], cum[idx + 1] - cum[idx], out=np.zeros_like(target),
                         where=cum[idx + 1] > cum[idx])
        u = lo + frac * (hi - lo)
        for _ in range(max_iterations):
            err = self.arc_length(u) - target
            err = np.atleast_1d(err)
            if np.all(np.abs(err) <= tolerance_mm):
                break
            lo = np.where(err < 0, u, lo)
            hi = np.where(err > 0, u, hi)
            speed = self.speeds(u)
            step = np.divide(err, speed, out=np.full_like(err, np.inf), where=speed > 0)
            newton = u - step
            u = np.where((newton > lo) & (newton < hi), newton, 0.5 * (lo + hi))
        return float(u[0]) if np.ndim(s) == 0 else u

