"""The toolpath R(s) = [P(s), O(s)] as a jerk-continuous function of the tool tip's arc
length s (Yuen thesis, seed 000, Eq. 3.12: the CL data are "fit to a jerk continuous
B-spline as a function of tangential displacement, s, to preserve third order continuity").

Method (`ArcLengthPath.fit`):

1. Parameter u = cumulative chord length of the tool tips (u_0 = 0).
2. P(u): quintic (k = 5) interpolating B-spline through the tips (scipy
   `make_interp_spline`; periodic when the path is closed, i.e. its first and last point and
   axis are equal, otherwise not-a-knot ends). A quintic spline is C4 in u, so P is
   jerk-continuous. The seed's own feed spline is degree 2 (seed-notes.md "Feed spline");
   we use degree 5 for the C3 requirement.
3. o(u): the same quintic interpolation of the tool-axis components, O = o / |o|.
4. Arc length s(u) = integral of |P'(u)| du, by 16-point Gauss-Legendre per knot span
   (|P'| is the square root of a degree-8 polynomial on a span and close to 1 in chord
   length: the quadrature error is at rounding level, ~1e-16 relative; on a span where |P'|
   varies tenfold, from wildly uneven points, it is ~1e-10).
5. s -> u is inverted exactly (not approximated by a second spline): the knot span is found
   from the knot arc lengths and Newton's method solves s(u) = s within the span, from the
   cubic Hermite interpolant of u(s) between the span's knots (du/ds = 1/|P'| there), each s
   until its step is at rounding level (4e-16 of the parameter length; two steps for most).
   Hence dP/ds = P'(u) / |P'(u)| is a unit vector to rounding (~1e-15), not merely to a
   fitting tolerance.
6. d^kP/ds^k and d^kO/ds^k (k = 1, 2, 3) follow analytically from the u-derivatives by the
   chain rule (Faa di Bruno) with u' = 1/|P'|, u'' = -(P'.P'')/|P'|^4, ...; derivatives of
   the normalized O from those of o. Since P, o are C4 in u and |P'| > 0, |o| > 0, R(s) is
   C3 in s: the jerk d^3P/ds^3 is continuous at the knots.

Accuracy: the path passes through the input points to rounding (~1e-17 m at 10 mm); as an
approximation of an underlying smooth curve the error is O(h^6) (h the point spacing): a
361-point circle of radius 4 mm gives 2 pi R to ~1e-14 relative (measured 6e-15).

Plain numpy/scipy, no rclpy.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline

from trajectory.blocks import BLOCK, in_blocks
from trajectory.toolpath import MIN_SPACING, CLData

DEGREE = 5  # quintic: C4 in u, so C3 (jerk-continuous) in s; thesis Eq. 3.12 asks for C3
_GL_X, _GL_W = np.polynomial.legendre.leggauss(16)  # assumed: 16 nodes, rounding-level on a span
_NEWTON_ITERATIONS = 12  # upper bound; convergence is quadratic, typically 2 steps from the Hermite start
# assumed: |o(u)| below this between two points means consecutive tool axes turn so far
# (towards opposite directions) that the interpolated axis is ill-defined.
_MIN_AXIS_NORM = 0.5
# assumed: |P'(u)| below this (chord length gives ~1) means the fitted curve nearly stops
# (a cusp from wildly uneven point spacing): arc length would be ill-conditioned.
_MIN_SPEED = 1e-3


def hermite_cubic(x, y0, y1, m0, m1):
    """The cubic with values y0, y1 and slopes m0, m1 at x = 0 and 1, at x (elementwise): the
    start of the Newton inversions here and in sampling.TimeLaw (from an interval's ends and
    their derivatives; its error ~ the interval^4)."""
    x2 = x * x
    x3 = x2 * x
    return ((2.0 * x3 - 3.0 * x2 + 1.0) * y0 + (x3 - 2.0 * x2 + x) * m0
            + (3.0 * x2 - 2.0 * x3) * y1 + (x3 - x2) * m1)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a . b over the last axis, kept as a length-1 axis."""
    return np.sum(a * b, axis=-1, keepdims=True)


def _lengths(v: np.ndarray) -> np.ndarray:
    """|v| over the last axis (3 components), summed in the order np.linalg.norm sums them
    (bit-identical), without its slow reduction over a short last axis (~40x here)."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.sqrt(x * x + y * y + z * z)


@dataclass(frozen=True)
class ArcLengthPath:
    """R(s) = [P(s), O(s)] for s in [0, length]; build with `ArcLengthPath.fit(cl)`."""
    position_spline: BSpline  # P(u), u = chord-length parameter
    axis_spline: BSpline      # o(u), un-normalized tool axis
    knot_u: np.ndarray        # (N,) u of the input points
    knot_s: np.ndarray        # (N,) arc length s of the input points (knot_s[-1] = length)
    knot_speed: np.ndarray    # (N,) |P'(u)| = ds/du at the input points
    closed: bool              # periodic spline (first point = last point)

    @property
    def length(self) -> float:
        """Arc length of the tool-tip path, m."""
        return float(self.knot_s[-1])

    @classmethod
    def fit(cls, cl: CLData) -> 'ArcLengthPath':
        p = np.array(cl.positions)
        o = np.array(cl.axes)
        closed = bool(np.linalg.norm(p[-1] - p[0]) < MIN_SPACING and np.allclose(o[-1], o[0], rtol=0, atol=1e-12))
        if closed:
            p[-1], o[-1] = p[0], o[0]
        u = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))))
        bc = 'periodic' if closed else None
        pos = make_interp_spline(u, p, k=DEGREE, bc_type=bc)
        axis = make_interp_spline(u, o, k=DEGREE, bc_type=bc)
        # quadrature nodes of every span, for the knot arc lengths and the sanity checks
        half = np.diff(u) / 2
        nodes = (u[:-1] + half)[:, None] + half[:, None] * _GL_X[None, :]
        speed = _lengths(pos(nodes, nu=1))
        bad = np.flatnonzero(speed.min(axis=1) < _MIN_SPEED)
        if len(bad):
            raise ValueError(f'the fitted path nearly stops between points {bad[0]} and {bad[0] + 1} '
                             '(very uneven point spacing)')
        bad = np.flatnonzero(_lengths(axis(nodes)).min(axis=1) < _MIN_AXIS_NORM)
        if len(bad):
            raise ValueError(f'tool axis turns too far between points {bad[0]} and {bad[0] + 1} '
                             '(interpolated axis nearly zero)')
        s = np.concatenate(([0.0], np.cumsum((speed * _GL_W).sum(axis=1) * half)))
        knot_speed = _lengths(pos(u, nu=1))
        for a in (u, s, knot_speed):
            a.setflags(write=False)
        return cls(pos, axis, u, s, knot_speed, closed)

    # ------------------------------------------------------------ s -> u

    def _speed(self, u):
        return _lengths(self.position_spline(u, nu=1))

    def parameter(self, s) -> np.ndarray:
        """The chord-length parameter u at arc length(s) s (exact inversion, see module)."""
        s = np.asarray(s, dtype=float)
        if not np.isfinite(s).all():
            raise ValueError('arc length s must be finite')
        tol = 1e-12 * max(self.length, 1.0)
        if (s < -tol).any() or (s > self.length + tol).any():
            raise ValueError(f'arc length s outside [0, {self.length:.17g}] m')
        s = np.clip(s, 0.0, self.length)
        i = np.clip(np.searchsorted(self.knot_s, s, side='right') - 1, 0, len(self.knot_s) - 2)
        u0, u1 = self.knot_u[i], self.knot_u[i + 1]
        s0 = self.knot_s[i]
        u = np.clip(self._hermite(i, s), u0, u1)
        rounding = 4e-16 * self.knot_u[-1]

        def newton_step(u0, u, s0, s):
            half = (u - u0) / 2
            nodes = (u0 + half)[..., None] + half[..., None] * _GL_X
            f = s0 + (self._speed(nodes) * _GL_W).sum(axis=-1) * half - s
            return f / self._speed(u)

        shape, u = u.shape, u.reshape(-1)
        moving, u0, u1, s0, s = np.arange(u.size), u0.reshape(-1), u1.reshape(-1), s0.reshape(-1), s.reshape(-1)
        for _ in range(_NEWTON_ITERATIONS):
            now = u[moving]
            # in blocks (trajectory/blocks.py): 16 nodes x 3 components per s
            step = in_blocks(newton_step, u0, now, s0, s, size=BLOCK // 8)
            u[moving] = np.clip(now - step, u0, u1)
            left = np.abs(step) > rounding
            if not left.any():
                break
            moving, u0, u1, s0, s = moving[left], u0[left], u1[left], s0[left], s[left]
        return u.reshape(shape)

    def _hermite(self, i, s) -> np.ndarray:
        """u(s)'s cubic Hermite interpolant on knot span i (du/ds = 1/|P'(u)| at its ends)."""
        ds = self.knot_s[i + 1] - self.knot_s[i]
        return hermite_cubic((s - self.knot_s[i]) / ds, self.knot_u[i], self.knot_u[i + 1],
                             ds / self.knot_speed[i], ds / self.knot_speed[i + 1])

    # ------------------------------------------------------------ evaluation

    def evaluate(self, s):
        """P(s) (m) and unit O(s): shape (3,) each for scalar s, (M, 3) for an array."""
        u = self.parameter(s)
        o = self.axis_spline(u)
        return self.position_spline(u), o / _lengths(o)[..., None]

    def tangents(self, s):
        """[(P, O), (P', O')] at s, from one s -> u inversion: the same numbers as
        :meth:`evaluate` and ``derivatives(s, 1)`` (their formulas), at about half the cost
        of calling both."""
        u = self.parameter(s)
        p1 = self.position_spline(u, nu=1)
        u1 = 1 / np.sqrt(_dot(p1, p1))                  # du/ds
        o0, o1 = self.axis_spline(u), self.axis_spline(u, nu=1)
        r = np.sqrt(_dot(o0, o0))
        n = o0 / r
        n1 = (o1 - _dot(o0, o1) / r * n) / r
        return [(self.position_spline(u), o0 / _lengths(o0)[..., None]), (p1 * u1, n1 * u1)]

    def derivatives(self, s, order: int):
        """(d^k P/ds^k, d^k O/ds^k) for k = order in {1, 2, 3}, shapes as `evaluate`."""
        if order not in (1, 2, 3):
            raise ValueError(f'derivative order must be 1, 2 or 3, got {order!r}')
        return self.all_derivatives(s)[order]

    def all_derivatives(self, s):
        """[(P, O), (P', O'), (P'', O''), (P''', O''')] with ' = d/ds, at s."""
        u = self.parameter(s)
        p1, p2, p3 = (self.position_spline(u, nu=k) for k in (1, 2, 3))
        g = np.sqrt(_dot(p1, p1))                       # |P'(u)| = ds/du
        gu = _dot(p1, p2) / g
        guu = (_dot(p2, p2) + _dot(p1, p3) - gu**2) / g
        u1 = 1 / g                                     # du/ds
        u2 = -gu / g**3                                # d2u/ds2
        u3 = (-guu / g**3 + 3 * gu**2 / g**4) / g      # d3u/ds3

        def in_s(f1, f2, f3):  # Faa di Bruno: d^k/ds^k f(u(s)) from the u-derivatives
            return (f1 * u1, f2 * u1**2 + f1 * u2, f3 * u1**3 + 3 * f2 * u1 * u2 + f1 * u3)

        # normalized axis n = o / r and its u-derivatives, from o = r n differentiated
        o0, o1, o2, o3 = (self.axis_spline(u, nu=k) for k in (0, 1, 2, 3))
        r = np.sqrt(_dot(o0, o0))
        r1 = _dot(o0, o1) / r
        r2 = (_dot(o1, o1) + _dot(o0, o2) - r1**2) / r
        r3 = (3 * _dot(o1, o2) + _dot(o0, o3) - 3 * r1 * r2) / r
        n = o0 / r
        n1 = (o1 - r1 * n) / r
        n2 = (o2 - r2 * n - 2 * r1 * n1) / r
        n3 = (o3 - r3 * n - 3 * r2 * n1 - 3 * r1 * n2) / r

        P = in_s(p1, p2, p3)
        O = in_s(n1, n2, n3)
        p0 = self.position_spline(u)
        return [(p0, n), (P[0], O[0]), (P[1], O[1]), (P[2], O[2])]
