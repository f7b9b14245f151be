"""The feed profile between its nodes, as the time law (sampling.TimeLaw, Yuen thesis Eq.
3.38) takes it: b(s) = E(s) g(s), E the rest shape (:func:`rest_shape`), g the uniform cubic
B-spline whose control points are b[n] / E(s[n]) (:func:`profile_spline`; sampling's module
docstring says why). The feed optimizer bounds b at the nodes only; :func:`feed_headroom`
is the factor on its feed bound that keeps b(s) within it between the nodes too.
"""
from __future__ import annotations

import functools

import numpy as np

from trajectory.blocks import BLOCK, in_blocks

# assumed: points per feed interval at which feed_headroom evaluates b(s): b is smooth within an
# inner interval (64 find the same largest value as 4096 on a 25 mm path of 1000 nodes), and in
# the two at each end, where E ~ d^(4/3) is not (4096: within 5e-9 of 65536; 64 there read
# 1.5e-5 low on a short grid). The sampler's feed check, at 1.001, catches any rest.
HEADROOM_POINTS = 64
HEADROOM_POINTS_AT_THE_ENDS = 4096


def rest_shape(d, length):
    """E(s) = (s (L - s) / L)^(4/3) at d = s - s[0] on a path of length L: sdot ~ d^(2/3), the
    shape of a constant-jerk start from rest and stop (the rest envelope of feedrate.py)."""
    x = np.clip(d * (length - d) / length, 0.0, None)
    return x * np.cbrt(x)


class UniformCubic:
    """A uniform cubic B-spline g(x) on [0, length] (h = length / spans; control points
    `coefficients`, one more than the knots on either side), evaluated span by span with
    the closed-form basis, in blocks (trajectory/blocks.py): scipy's BSpline (the same
    curve, its numbers within rounding: tested) searches the knots for every point, ~15x
    slower on the millions of points the time law evaluates."""

    def __init__(self, length: float, coefficients):
        self.length = float(length)
        self.coefficients = np.asarray(coefficients, float)
        self.spans = len(self.coefficients) - 3
        self.h = self.length / self.spans

    def __call__(self, x, nu: int = 0) -> np.ndarray:
        """g(x), g'(x) or g''(x) (nu = 0, 1, 2) at x (any shape) in [0, length]."""
        if nu not in (0, 1, 2):
            raise ValueError(f'derivative order must be 0, 1 or 2, got {nu!r}')
        x = np.asarray(x, float)
        return in_blocks(lambda x: self._block(x, nu), x.reshape(-1), size=8 * BLOCK).reshape(x.shape)

    def _block(self, x, nu: int) -> np.ndarray:
        i = np.clip(np.floor(x / self.h).astype(np.intp), 0, self.spans - 1)
        t = (x - i * self.h) / self.h            # from the span's knot i h: as exact as x
        c0, c1, c2, c3 = (self.coefficients[i + k] for k in range(4))
        r = 1.0 - t
        if nu == 0:
            t2 = t * t
            return (r * r * r * c0 + (3.0 * t2 * t - 6.0 * t2 + 4.0) * c1
                    + (((-3.0 * t + 3.0) * t + 3.0) * t + 1.0) * c2 + t2 * t * c3) / 6.0
        if nu == 1:
            return (-r * r * c0 + (3.0 * t - 4.0) * t * c1 + ((-3.0 * t + 2.0) * t + 1.0) * c2
                    + t * t * c3) / (2.0 * self.h)
        return (r * c0 + (3.0 * t - 2.0) * c1 + (1.0 - 3.0 * t) * c2 + t * c3) / (self.h * self.h)


def control_point_spline(d, c) -> UniformCubic:
    """Uniform cubic B-spline on the nodes d (uniform, d[0] = 0) with control point c[n]
    centred on node n, and ghost points 2 c[0] - c[1], 2 c[-1] - c[-2] (clipped >= 0) past
    the ends, so its value at either end is c there. At node n its second derivative is
    (c[n-1] - 2 c[n] + c[n+1]) / h², its first (c[n+1] - c[n-1]) / (2 h): the LP's central
    differences; its value (c[n-1] + 4 c[n] + c[n+1]) / 6 lies within the control points."""
    h = (d[-1] - d[0]) / (len(d) - 1)
    if not np.allclose(np.diff(d), h, rtol=1e-9, atol=0.0):
        raise ValueError('the feed profile needs uniformly spaced nodes')
    ghosts = np.maximum([2.0 * c[0] - c[1], 2.0 * c[-1] - c[-2]], 0.0)
    return UniformCubic(d[-1] - d[0], np.concatenate(([ghosts[0]], c, [ghosts[1]])))


def profile_spline(d, b) -> UniformCubic:
    """g of the profile b on the uniform nodes d (d[0] = 0): control points b[n] / E(d[n]),
    at the rest ends (E = 0) the neighbour's ratio continued."""
    e = rest_shape(d, d[-1])
    g = np.empty_like(b)
    g[1:-1] = np.maximum(b[1:-1], 0.0) / e[1:-1]
    g[0], g[-1] = g[1], g[-2]
    return control_point_spline(d, g)


def feed_headroom(s) -> np.ndarray:
    """Per node of the uniform grid s, the factor (<= 1) on the feed bound F^2 that keeps b(s)
    <= F^2 between the nodes too. b(s) is E(s) times non-negative weights (summing to 1) of
    the four control points b[j] / E(s[j]) around s, so where every b[j] is at F^2 it is
    F^2 r(s), r the profile b = 1's, which rises over 1 where E bends: on a 25 mm path with
    1000 nodes r is 1.217 within 0.1 mm of the rest ends (sdot 10 % over F), 1.008 at 0.25 mm,
    1.0003 at 1 mm, 1 from 6 mm on.
    A node's factor is 1 / the largest r over the four intervals its control point weighs
    on; then for any b[j] <= F^2 factor[j], b(s) <= F^2 r(s) / max r <= F^2. r between
    nodes is sampled (HEADROOM_POINTS). End nodes (at rest, b = 0): 0. It depends on the
    grid's length and node count only: computed once per grid (the re-solves of a plan ask
    again), a read-only array."""
    s = np.asarray(s, float)
    return _headroom(float(s[-1] - s[0]), len(s))


@functools.lru_cache(maxsize=8)
def _headroom(length: float, nodes: int) -> np.ndarray:
    d = np.linspace(0.0, length, nodes)
    spline = profile_spline(d, np.ones(nodes))

    def rise(intervals, points):
        x = np.minimum((intervals[:, None] + np.linspace(0.0, 1.0, points + 1)) * spline.h, length)
        return np.max(rest_shape(x, length) * spline(x), axis=1)
    count = nodes - 1
    at_ends = np.isin(np.arange(count), [0, 1, count - 2, count - 1])
    r = np.empty(count)                                                 # per interval
    r[~at_ends] = rise(np.flatnonzero(~at_ends), HEADROOM_POINTS)
    r[at_ends] = rise(np.flatnonzero(at_ends), HEADROOM_POINTS_AT_THE_ENDS)
    # node j's control point weighs on intervals j-2 .. j+1 (those that exist)
    padded = np.concatenate(([0.0, 0.0], r, [0.0, 0.0]))
    worst = np.max([padded[k:k + len(d)] for k in range(4)], axis=0)
    headroom = np.divide(1.0, worst, out=np.zeros_like(worst), where=worst > 0)
    headroom[0] = headroom[-1] = 0.0
    headroom.flags.writeable = False
    return headroom
