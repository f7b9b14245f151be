"""Interpolation and time sampling of a resolved path (Yuen thesis section 3.10,
Eqs. 3.38-3.40): axis references at the control period from q(s) and the feed profile.

**Septic interpolation (Eqs. 3.39-3.40).** Between the resolution nodes s[n], s[n+1] each
axis is the 7th-order polynomial that matches q, q', q'', q''' (d/ds) at both ends, so q(s)
is C3 in s. The coefficients solve the 8 x 8 system of Eq. 3.40; here it is solved once on
the normalized interval u = (s - s[n]) / Δs in [0, 1] (the data scaled by Δs^k), and the
polynomial is written about s[n] (q[n] + sum_k c_k u^k) instead of in powers of the global
s, which keeps the round-off at the size of q's own (Eq. 3.39 as printed, in powers of s,
would lose digits for s >> Δs).

**Time law (Eq. 3.38).** The thesis steps s[k+1] = s[k] + sdot T + sddot T²/2 with the
feed of the optimizer; that explicit step cannot leave a rest point (sdot = sddot = 0
there) and its error accumulates. Here s(t) is the exact solution of ds/dt = sdot(s) with
sdot(s) = sqrt(b(s)), b the feed profile:

* b between the feed nodes: b(s) = E(s) g(s), E(s) = (s (L - s) / L)^(4/3) the shape of a
  constant-jerk start from rest at s = 0 and stop at s = L (sdot ~ d^(2/3), which is the
  rest envelope feedrate.py bounds b with), g the uniform cubic B-spline whose control
  points c[n] = b[n] / E(s[n]) (>= 0) on the feed nodes. Not the interpolating spline: g''
  at node n is (c[n-1] - 2 c[n] + c[n+1]) / Δs², the second difference the optimizer's jerk
  rows constrain (for b; E varies slowly away from the ends), and g there is
  (c[n-1] + 4 c[n] + c[n+1]) / 6, within the control points; an interpolating cubic through
  a profile whose second differences
  alternate in sign (the LP where the jerk rows are active) has up to 3x that at the nodes.
  So b is C2 inside the path and the ends are reached at rest with finite jerk.
* ds/dt = sqrt(E g) is singular at the rest ends (1/sdot is not integrable by plain
  quadrature and the ODE does not leave s = 0). With s = L h(u), h(u) = u³(10 - 15u + 6u²)
  (h' = 30 u² (1 - u)² vanishes to second order at both ends, like sdot), the ODE becomes
  du/dt = f(u) = L^(-1/3) (p(u) p(1 - u))^(2/3) sqrt(g(s)) / 30, p(u) = 10 - 15u + 6u²,
  which is smooth and positive on [0, 1]. t(u) = ∫ du / f is computed with Gauss-Legendre
  quadrature on the u-images of the feed nodes (f is smooth inside each), and u(t_k) by
  Newton's method on t(u) = t_k: s(t) is exact to round-off, so finite differences of the
  sampled positions see the planned motion, not integration noise.
* The duration is stretched to a whole number K of control periods (at most one period),
  so the last sample t_K = K T is the path end at rest.
* References: qdot = q' sdot, qddot = q'' sdot² + q' sddot with sddot = b'(s) / 2.

**Verification.** The feed optimizer only checks its grid. The sampled positions, padded
with three rest samples on either side (the machine holds before and after), are
differenced at the control period (velocity, acceleration, jerk) by `sample_profile`, and
the tool's feed sdot (exact: s is the tool's arc length) is held against the process feed
limit F as one more velocity (where over F, a re-solve asks its velocity factor for it,
which scales F too). The feed bound's headroom (feed_shape.py) keeps
b within F^2 between the nodes, so this check does not slow a plan down; without both, every
feed-limited micromill plan ran 10 % over F near its rest ends. Where a sample exceeds its
limit, the profile is slowed down and sampled again: one loop,
:func:`sample_within`, with the slow-down rule as a parameter. :func:`resolve_rule` (the
planner's first stage: planner.feed_and_sample) lowers the exceeded limit at the feed nodes
around the offending samples (:func:`limit_scales`) and re-solves the feed LP in a window
around them (feedrate.refine_feed): the new dips keep the grid's jerk rows, where a dip
multiplied into b (the slow-down this replaces) added its own jerk and, on the helix at
F = 1 m/s with the jerk limit binding along the whole path, made new violations at every
pass (8 passes did not converge; a global stretch by 0.86 then cost 22 %).
:func:`global_stretch` scales b by the exact factor of a time stretch (v ~ c^(1/2), a ~ c,
j ~ c^(3/2)) — :func:`sample`, the fallback, which resamples until every axis is within
`tolerance` x its limit (and the feed within `tolerance` x F), at most `max_passes` times.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from machine_ctrl.model.reference import Reference
from trajectory.blocks import in_blocks
from trajectory.feed_shape import UniformCubic, profile_spline, rest_shape
from trajectory.feedrate import FeedLimits, refine_feed
from trajectory.spline import hermite_cubic

# Eq. 3.40 with Δs = 1 (rows: q[n], q[n+1], q'[n], q'[n+1], q''[n], q''[n+1], q'''[n],
# q'''[n+1]; columns: coefficients of u^7 ... u^0).
_EQ_340 = np.array([
    [0, 0, 0, 0, 0, 0, 0, 1],
    [1, 1, 1, 1, 1, 1, 1, 1],
    [0, 0, 0, 0, 0, 0, 1, 0],
    [7, 6, 5, 4, 3, 2, 1, 0],
    [0, 0, 0, 0, 0, 2, 0, 0],
    [42, 30, 20, 12, 6, 2, 0, 0],
    [0, 0, 0, 0, 6, 0, 0, 0],
    [210, 120, 60, 24, 6, 0, 0, 0]], dtype=float)
_EQ_340_INV = np.linalg.inv(_EQ_340)
_GL_X, _GL_W = np.polynomial.legendre.leggauss(10)
# assumed: a re-solve (resolve_rule) aims the exceeded limit 1 % below the sampled overshoot
# (0.5 % took one more pass on helix and spiral at F = 1 for 0.2 % less time).
TIGHTEN_MARGIN = 0.99
# assumed: a re-solve frees 32 feed nodes either side of a tightened one; 8 and 16 were
# infeasible (too little room for the dip) on helix and spiral at F = 1, and doubled to 32.
REFINE_WINDOW = 32
# assumed: a re-solve makes at most 3 LP iterations (its jerk rows linearized about the
# previous profile first); 8 (to the optimizer's 1e-3 convergence) cost circle_xy at F = 1
# 9.6 s instead of 6.4 s for the same traversal time, helix and spiral within 0.2 %.
REFINE_ITERATIONS = 3
# TimeLaw.u_at: Newton's steps at most (one from its Hermite start for most entries), and
# the relative step below which an entry has converged (Newton's error is then the rounding
# of t(u)).
_NEWTON_STEPS = 8
_U_ROUNDING = np.finfo(float).eps


class SepticInterpolant:
    """q(s) of Eqs. 3.39-3.40 through nodes s (N,) with q, q', q'', q''' (N, axes)."""

    def __init__(self, s, q, dq, ddq, dddq):
        s = np.asarray(s, float)
        data = [np.asarray(a, float) for a in (q, dq, ddq, dddq)]
        if s.ndim != 1 or len(s) < 2 or not np.all(np.isfinite(s)) or np.any(np.diff(s) <= 0):
            raise ValueError('septic interpolation needs >= 2 strictly increasing finite nodes')
        for a in data:
            if a.ndim != 2 or a.shape[0] != len(s) or not np.all(np.isfinite(a)):
                raise ValueError(f'node data must be finite with shape ({len(s)}, axes)')
        self.s = s
        self.q = data[0]
        h = np.diff(s)[:, None]
        # right-hand side of Eq. 3.40 on u in [0, 1]: derivatives scaled by h^k, q[n] taken out
        rhs = np.stack([np.zeros_like(data[0][:-1]), data[0][1:] - data[0][:-1],
                        data[1][:-1] * h, data[1][1:] * h,
                        data[2][:-1] * h**2, data[2][1:] * h**2,
                        data[3][:-1] * h**3, data[3][1:] * h**3], axis=1)      # (N-1, 8, axes)
        coef = np.einsum('ij,njk->nik', _EQ_340_INV, rhs)                       # u^7 ... u^0
        # per power of u (u^0 ... u^7), each (N-1, axes) contiguous: a sample gathers rows
        self._coef = [np.ascontiguousarray(coef[:, 7 - k, :]) for k in range(8)]
        self._h = h[:, 0]

    @classmethod
    def from_resolution(cls, resolution) -> SepticInterpolant:
        r = resolution
        return cls(r.s, r.q, r.dq, r.ddq, r.dddq)

    def evaluate(self, s, order: int = 0) -> np.ndarray:
        """d^order q / ds^order (order 0..3) at s (M,) -> (M, axes); s is clipped to the nodes."""
        return self.evaluate_orders(s, (order,))[0]

    def evaluate_orders(self, s, orders) -> list[np.ndarray]:
        """:meth:`evaluate` for each of `orders` at the same s, the interval of each s found once."""
        for order in orders:
            if order not in (0, 1, 2, 3):
                raise ValueError(f'derivative order must be 0..3, got {order!r}')
        return in_blocks(lambda s: self._orders(s, orders), np.atleast_1d(np.asarray(s, float)))

    def _orders(self, s, orders) -> list[np.ndarray]:
        n = np.clip(np.searchsorted(self.s, s, side='right') - 1, 0, len(self.s) - 2)
        h = self._h[n]
        u = ((np.clip(s, self.s[0], self.s[-1]) - self.s[n]) / h)[:, None]
        c = [coef[n] for coef in self._coef]                                    # 8 x (M, axes)
        values = []
        for order in orders:
            value = np.zeros((len(s), self.q.shape[1]))
            for k in range(7, order - 1, -1):                                   # Horner in u
                factor = math.perm(k, order)
                value = value * u + factor * c[k]
            if order == 0:
                value = value - c[0] + self.q[n]           # c_0 = 0 exactly; q[n] added unrounded
            values.append(value / h[:, None] ** order)
        return values


@dataclass(frozen=True)
class TimeLaw:
    """s(t) of a feed profile (module docstring): b(s) = scale * E(s) g(s)."""
    length: float
    g: UniformCubic
    floor: float
    u_nodes: np.ndarray          # u-images of the feed nodes
    t_nodes: np.ndarray          # t(u_nodes) at scale 1

    @classmethod
    def from_profile(cls, s, b) -> TimeLaw:
        s, b = np.asarray(s, float), np.asarray(b, float)
        if len(s) < 4 or len(b) != len(s) or not np.all(np.isfinite(b)) or np.any(np.diff(s) <= 0):
            raise ValueError('the feed profile needs >= 4 finite nodes on increasing s')
        length = float(s[-1] - s[0])
        d = s - s[0]
        spline = profile_spline(d, b)
        if not np.max(spline.coefficients) > 0:
            raise ValueError('the feed profile is zero everywhere')
        floor = 1e-9 * float(np.max(spline.coefficients))   # keeps f > 0: the path never stalls inside
        u_nodes = _inverse_smoothstep(d / length)
        law = cls(length, spline, floor, u_nodes, np.zeros(len(d)))
        pieces = law._integral(u_nodes[:-1], u_nodes[1:])
        object.__setattr__(law, 't_nodes', np.concatenate(([0.0], np.cumsum(pieces))))
        return law

    @property
    def duration(self) -> float:
        return float(self.t_nodes[-1])

    def rate(self, u) -> np.ndarray:
        """f(u) = du/dt at scale 1."""
        return self._rate(u, self.g(self.length * _h(u)))

    def _rate(self, u, g) -> np.ndarray:
        """f(u) from g at s(u)."""
        g = np.maximum(g, self.floor)
        return self.length ** (-1.0 / 3.0) * (_p(u) * _p(1.0 - u)) ** (2.0 / 3.0) * np.sqrt(g) / 30.0

    def _integral(self, a, b) -> np.ndarray:
        """∫_a^b du / f(u), elementwise (Gauss-Legendre, f smooth between feed nodes)."""
        def integral(a, b):
            half = (b - a) / 2.0
            mid = (a + b) / 2.0
            nodes = mid[:, None] + half[:, None] * _GL_X[None, :]
            return half * np.sum(_GL_W / self.rate(nodes), axis=1)
        return in_blocks(integral, a, b)

    def u_at(self, t) -> np.ndarray:
        """u with t(u) = t (scale 1, t an array or a number: an array of u either way), by
        Newton's method within the bracketing feed nodes. It starts from the cubic Hermite
        interpolant of u(t) between them (du/dt = f at both; error ~ their spacing^4). An
        entry stops once its step is at most eps |u| (a unit or two in u's last place), or
        once the error the step leaves is estimated below a sixteenth of that: Newton's
        a-posteriori error |t''/2t'| step^2 = |f'/2f| step^2, plus |step| times the feed
        interval's :meth:`_quadrature_slip` (where the quadrature's t(u) has a slope other
        than 1/f, Newton converges only linearly, at that rate). One step for most entries;
        u then solves t(u) = t to the rounding of t(u) itself (more steps only move it within
        that)."""
        t = np.clip(np.atleast_1d(np.asarray(t, float)), 0.0, self.duration)
        i = np.clip(np.searchsorted(self.t_nodes, t, side='right') - 1, 0, len(self.t_nodes) - 2)
        lo, hi = self.u_nodes[i], self.u_nodes[i + 1]
        u = np.clip(self._hermite(i, t), lo, hi)
        start = self.t_nodes[i]
        slip = self._quadrature_slip()[i]
        moving = np.arange(len(u))
        for _ in range(_NEWTON_STEPS):
            now = u[moving]
            residual = start + self._integral(lo, now) - t
            rate, slope = self._rate_and_log_slope(now)
            step = residual * rate
            new = now - step
            u[moving] = np.clip(new, lo, hi)
            rounding = _U_ROUNDING * np.abs(new)
            error = (slip + np.abs(slope) / 2 * np.abs(step)) * np.abs(step)
            left = (np.abs(step) > rounding) & ((error > rounding / 16) | (new < lo) | (new > hi))
            if not left.any():
                break
            moving, lo, hi, t, start, slip = moving[left], lo[left], hi[left], t[left], start[left], slip[left]
        return u

    def _quadrature_slip(self) -> np.ndarray:
        """Per feed interval, how far the slope of the quadrature's t(u) (Gauss-Legendre from
        the interval's start, :meth:`_integral`) strays from 1/f, relative: |t'(u) f(u) - 1|,
        the largest at a quarter, half, three quarters and the whole of the interval, times 4
        (assumed: a margin for the points between; Gauss-Legendre's error grows with the
        length integrated). ~1e-16 where f is smooth over the interval; up to ~1e-3 where g
        changes tenfold within it."""
        lo, hi = self.u_nodes[:-1, None], self.u_nodes[1:, None]
        u = lo + (hi - lo) * np.array([0.25, 0.5, 0.75, 1.0])                   # (intervals, 4)
        half = (u - lo) / 2
        x = (lo + half)[..., None] + half[..., None] * _GL_X                     # (intervals, 4, nodes)
        rate, slope = self._rate_and_log_slope(x)
        # d/du of half * sum(w / f(x)), x = lo + half (1 + xi): the quadrature's t'(u)
        t1 = np.sum(_GL_W / rate, axis=-1) / 2 - half * np.sum(_GL_W * slope / rate * (1 + _GL_X) / 2, axis=-1)
        return 4.0 * np.max(np.abs(t1 * self.rate(u) - 1.0), axis=-1)

    def _rate_and_log_slope(self, u):
        """f(u) (:meth:`rate`) and d ln f / du = 2/3 (p'(u)/p(u) - p'(1-u)/p(1-u)) + g'/2g
        (g' = 0 where the floor holds g)."""
        d = self.length * _h(u)
        g = self.g(d)
        dg = np.where(g > self.floor, self.g(d, 1) * self.length * 30.0 * (u * (1.0 - u)) ** 2, 0.0)
        slope = ((2.0 / 3.0) * ((12.0 * u - 15.0) / _p(u) + (12.0 * u + 3.0) / _p(1.0 - u))
                 + dg / (2.0 * np.maximum(g, self.floor)))
        return self._rate(u, g), slope

    def _hermite(self, i, t) -> np.ndarray:
        """u(t)'s cubic Hermite interpolant on feed interval i (du/dt = f(u) at its ends)."""
        f = self.rate(self.u_nodes)
        dt = self.t_nodes[i + 1] - self.t_nodes[i]
        return hermite_cubic((t - self.t_nodes[i]) / dt, self.u_nodes[i], self.u_nodes[i + 1],
                             dt * f[i], dt * f[i + 1])

    def feed(self, s):
        """(sdot, sddot) at s (scale 1): sqrt(b) and b'/2."""
        d = np.asarray(s, float)
        e = rest_shape(d, self.length)
        g = self.g(d)
        dg = np.where(g > self.floor, self.g(d, 1), 0.0)
        g = np.maximum(g, self.floor)
        x = np.clip(d * (self.length - d) / self.length, 0.0, None)
        de = (4.0 / 3.0) * np.cbrt(x) * (self.length - 2.0 * d) / self.length
        return np.sqrt(e * g), 0.5 * (de * g + e * dg)


def _p(u):
    return 10.0 - 15.0 * u + 6.0 * u * u


def _h(u):
    return u ** 3 * _p(u)


def _inverse_smoothstep(y) -> np.ndarray:
    """u in [0, 1] with h(u) = y (bisection to round-off; h is monotone)."""
    y = np.asarray(y, float)
    lo, hi = np.zeros_like(y), np.ones_like(y)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        below = _h(mid) < y
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    u = 0.5 * (lo + hi)
    u[y <= 0.0], u[y >= 1.0] = 0.0, 1.0
    return u


def _ratios(position, period, velocity, acceleration, jerk):
    """Peak ratios (axes, 3) and, per sample (K+1, 3), the worst ratio over the axes of
    |velocity|, |acceleration|, |jerk| by finite differences to its limit."""
    p = np.asarray(position, float)
    p = np.vstack([np.repeat(p[:1], 3, axis=0), p, np.repeat(p[-1:], 3, axis=0)])
    n = len(position)
    per_sample = np.zeros((n, 3))
    peaks = []
    for k, limit in ((1, velocity), (2, acceleration), (3, jerk)):
        r = np.abs(np.diff(p, k, axis=0)) / period**k / limit
        peaks.append(np.max(r, axis=0))
        # difference j covers padded samples j..j+k, i.e. samples j-3..j+k-3
        idx = np.clip(np.arange(len(r)) - 3 + k // 2, 0, n - 1)
        np.maximum.at(per_sample[:, k - 1], idx, np.max(r, axis=1))
    return np.column_stack(peaks), per_sample


@dataclass(frozen=True)
class Sampling:
    """Result of :func:`sample_profile` and :func:`sample`."""
    reference: Reference
    s: np.ndarray                # (K+1,) path displacement of every sample, m
    sdot: np.ndarray             # (K+1,) m/s
    feed_scale: float            # final global factor on b (1: the profile as given)
    passes: int                  # sampling passes made (1 + rescalings)
    peak_ratios: np.ndarray      # (axes, 3) finite-difference peak |v|, |a|, |j| / limit
    ratios: np.ndarray           # (K+1, 3) per sample: worst |v|, |a|, |j| / limit over the axes
    feed_ratios: np.ndarray | None = None   # (K+1,) sdot / the process feed limit F (None: no F)

    @property
    def feed_ratio(self) -> float:
        """Peak sdot / F (0 without a feed limit)."""
        return 0.0 if self.feed_ratios is None else float(np.max(self.feed_ratios))

    @property
    def duration(self) -> float:
        return (len(self.s) - 1) * self.reference.period

    @property
    def peak(self) -> float:
        """The largest ratio to a limit: an axis's velocity, acceleration, jerk or the feed."""
        return max(float(np.max(self.peak_ratios)), self.feed_ratio)

    @property
    def need(self) -> np.ndarray:
        """(K+1,) per sample: the factor on b a time stretch would need (v and the feed ~
        b^1/2, a ~ b, j ~ b^3/2)."""
        need = np.max(self.ratios ** np.array([2.0, 1.0, 2.0 / 3.0]), axis=1)
        return need if self.feed_ratios is None else np.maximum(need, self.feed_ratios ** 2)

    def velocity_asks(self) -> np.ndarray:
        """(K+1,) per sample: the velocity ratio a re-solve answers (:func:`limit_scales`): the
        axes', or sdot / F where the feed is over its limit (exact, not a finite difference:
        a feed at its limit along a whole cruise is no overshoot to pull down)."""
        if self.feed_ratios is None:
            return self.ratios[:, 0]
        return np.where(self.feed_ratios > 1.0, np.maximum(self.ratios[:, 0], self.feed_ratios), self.ratios[:, 0])


def _limit_arrays(limits):
    return tuple(np.asarray(getattr(limits, k), float) for k in ('velocity', 'acceleration', 'jerk'))


def sample_profile(interpolant: SepticInterpolant, feed_s, feed_b, limits, period: float,
                   axis_names, scale: float = 1.0) -> Sampling:
    """One pass of Eq. 3.38 (module docstring): references at the control period `period` (s)
    along the interpolated path following the feed profile scale * b (= sdot², nodes
    feed_s, feed_b), with their finite-difference peak ratios to `limits` (velocity,
    acceleration, jerk arrays, e.g. a feedrate.FeedLimits, and its process feed limit `feed`
    on sdot where it has one); no check against them."""
    if not (period > 0 and math.isfinite(period)):
        raise ValueError(f'control period must be > 0 s, got {period!r}')
    feed_s = np.asarray(feed_s, float)
    if abs(feed_s[0] - interpolant.s[0]) > 1e-12 or abs(feed_s[-1] - interpolant.s[-1]) > 1e-9:
        raise ValueError('the feed profile must span the interpolated path')
    b = np.maximum(np.asarray(feed_b, float), 0.0)
    law = TimeLaw.from_profile(feed_s - feed_s[0], scale * b)
    duration = law.duration
    steps = max(3, math.ceil(duration / period - 1e-9))
    stretch = steps * period / duration                 # >= 1: whole number of periods
    u = law.u_at(np.arange(steps + 1) * (duration / steps))
    u[0], u[-1] = 0.0, 1.0
    d = law.length * _h(u)
    d[-1] = law.length
    sdot, sddot = law.feed(d)
    sdot, sddot = sdot / stretch, sddot / stretch**2
    sdot[0] = sdot[-1] = sddot[0] = sddot[-1] = 0.0
    s = d + interpolant.s[0]
    q, dq, ddq = interpolant.evaluate_orders(s, (0, 1, 2))
    peaks, per_sample = _ratios(q, period, *_limit_arrays(limits))
    feed = getattr(limits, 'feed', None)       # s is the tool's arc length: sdot its exact speed
    reference = Reference(tuple(axis_names), period, q, dq * sdot[:, None],
                          ddq * sdot[:, None] ** 2 + dq * sddot[:, None])
    return Sampling(reference, s, sdot, scale / stretch**2, 1, peaks, per_sample, sdot / feed if feed else None)


class LimitsExceeded(ValueError):
    """No slow-down within its passes brought every sampled reference within tolerance."""


@dataclass(frozen=True)
class Refinement:
    """Result of :func:`sample_within`: the last Sampling (with `passes` set), whether its
    peaks are within the tolerance, and the feed nodes b and global scale after the last
    slow-down (what a further stage would start from)."""
    sampling: Sampling
    within: bool
    feed_b: np.ndarray
    scale: float


def sample_within(interpolant: SepticInterpolant, feed_s, feed_b, limits, period: float, axis_names,
                  slow_down, tolerance: float, max_passes: int) -> Refinement:
    """The sampling loop: :func:`sample_profile` of scale * b; while a finite-difference
    peak exceeds `tolerance` x its limit, `slow_down(result, b, scale) -> (b, scale)` (a
    slow-down rule: :func:`global_stretch`, :func:`resolve_rule`) and sample again, at most
    `max_passes` samplings. The rule is applied after every pass that misses, the last one
    too."""
    b, scale = feed_b, 1.0
    for passes in range(1, max_passes + 1):
        result = replace(sample_profile(interpolant, feed_s, b, limits, period, axis_names, scale),
                         passes=passes)
        if result.peak <= tolerance:
            return Refinement(result, True, b, scale)
        b, scale = slow_down(result, b, scale)
    return Refinement(result, False, b, scale)


def global_stretch(result: Sampling, feed_b, scale: float):
    """Slow-down rule of a global time stretch: the whole profile scaled by the factor the
    worst sample needs (v ~ c^(1/2), a ~ c, j ~ c^(3/2))."""
    # assumed: aim 0.1 % below the limit so the next pass lands inside the tolerance
    return feed_b, scale * 0.999 / float(np.max(result.need))


def limit_scales(result: Sampling, feed_s, margin: float = TIGHTEN_MARGIN) -> np.ndarray:
    """Per feed node (N, 3) factors (<= 1) on the velocity, acceleration and jerk limits that
    bring every sample of `result` to at most `margin` x its limits: a sample at r > margin
    times a limit asks for margin / r on that limit at every node whose control point shapes
    the time law between the samples of its finite differences (samples k-1 .. k+2 of sample
    k, _ratios): from node n-1 of the span [s_n, s_n+1] of sample k-1 to node m+2 of the span
    of sample k+2 (g is a cubic B-spline, four control points per span; module docstring). A
    node takes the smallest ask. (Asking only where a sample is over its limit leaves those
    just below it to rise over it in the re-solve: one more pass on helix and spiral at
    F = 1.)"""
    feed_s = np.asarray(feed_s, float)
    n, last = len(feed_s), len(result.s) - 1
    scales = np.ones((n, 3))
    ratios = np.column_stack((result.velocity_asks(), result.ratios[:, 1:]))
    near = np.flatnonzero(np.max(ratios, axis=1) > margin)

    def span(k: np.ndarray) -> np.ndarray:          # the feed interval of samples k
        return np.clip(np.searchsorted(feed_s, result.s[np.clip(k, 0, last)], side='right') - 1, 0, n - 2)
    first, end = np.maximum(span(near - 1) - 1, 0), np.minimum(span(near + 2) + 2, n - 1)
    ask = np.minimum(margin / ratios[near], 1.0)
    for offset in range(int(np.max(end - first, initial=0)) + 1):
        inside = first + offset <= end
        np.minimum.at(scales, first[inside] + offset, ask[inside])
    return scales


def resolve_rule(feed_s, derivatives, limits: FeedLimits, margin: float = TIGHTEN_MARGIN,
                 window: int = REFINE_WINDOW):
    """Slow-down rule (:func:`sample_within`) of the windowed re-solve: each exceeded limit
    lowered at the nodes around the offending samples (:func:`limit_scales`, the factors
    accumulated over the passes) and b re-solved within `window` nodes of them, at most
    REFINE_ITERATIONS LP iterations (feedrate.refine_feed; derivatives: q', q'', q''' at the
    feed nodes feed_s). Should the LP fail, that pass is a :func:`global_stretch`."""
    scales = np.ones((len(feed_s), 3))

    def slow_down(result: Sampling, feed_b, scale: float):
        tighter = limit_scales(result, feed_s, margin)
        scales[:] = scales * tighter
        changed = np.flatnonzero(np.min(tighter, axis=1) < 1.0)
        try:
            return refine_feed(feed_s, feed_b, *derivatives, limits, scales, changed, window,
                               REFINE_ITERATIONS).b, scale
        except ValueError:                      # the LP failed: this pass stretches globally
            return global_stretch(result, feed_b, scale)
    return slow_down


def sample(interpolant: SepticInterpolant, feed_s, feed_b, limits, period: float,
           axis_names, tolerance: float = 1.001, max_passes: int = 6) -> Sampling:
    """:func:`sample_profile` with b scaled down globally until every finite-difference
    peak and the feed are within `tolerance` x their limits (module docstring, "Verification"); raises
    LimitsExceeded (a ValueError) when no scaling within `max_passes` meets `tolerance`."""
    outcome = sample_within(interpolant, feed_s, feed_b, limits, period, axis_names, global_stretch,
                            tolerance, max_passes)
    if not outcome.within:
        raise LimitsExceeded(f'sampled references exceed the limits by '
                             f'{outcome.sampling.peak:.4g}x after {max_passes} passes')
    return outcome.sampling
