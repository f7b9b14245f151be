"""Feed optimization (Yuen thesis section 3.9, Eqs. 3.29-3.37): the fastest traversal of a
resolved path q(s) such that every axis stays within its velocity, acceleration and jerk
limits and the tool within a process feed limit, starting and ending at rest.

The thesis optimizes the control points of a B-spline feed profile with a general NLP
solver and notes that it is slow. Here the unknown is b(s) = sdot^2 on the grid s[n] where
the path derivatives q', q'', q''' are known (from the redundancy resolution). With
sdot = sqrt(b), sddot = b'/2 and sdddot = sqrt(b) b''/2 (chain rule):

    qdot   = q' sqrt(b)                              (velocity: |q'| sqrt(b) <= v_max)
    qddot  = q'' b + q' b'/2                         (linear in b)
    qdddot = sqrt(b) (q''' b + 3/2 q'' b' + 1/2 q' b'')

Velocity (as b <= (v_max/|q'|)^2), feed (b <= F^2, lowered near the rest ends so that the
time law's b between the nodes keeps it too: feed_shape.feed_headroom) and acceleration are
linear in b;
the jerk constraint is linear once sqrt(b) is frozen at the previous iterate's value
(sequential linear programming, as in jerk-limited TOPP formulations). Each iteration
maximizes sum(b) (the usual linear surrogate of minimum time) with scipy's HiGHS LP;
b' and b'' are central differences on the uniform grid. A final check evaluates the true
(unfrozen) jerk and, if any exceeds its limit, scales b down uniformly (jerk scales with
b^(3/2)), so the returned profile satisfies every constraint on the grid.

End conditions: b = 0 at both ends (at rest). Near a rest point the grid differences
cannot represent the singular start (b ~ s^(4/3)), so b is also bounded by the exact
envelope of a constant-jerk start, sdot(d) = (j_t/2) (6 d/j_t)^(2/3) at distance d from
either end, with the tangential jerk limit j_t = min_i j_max,i/|q'_i| of that end (near rest
the axis jerk is q' sdddot): no profile starting from rest with |sdddot| <= j_t is faster.

Accuracy: the constraints hold at the grid points. Between them, and in the duration
estimate near the rest ends, the grid costs a few percent: on a straight line the profile's
duration is 3-5 % below Ruckig's time-optimal rest-to-rest move at 400-2000 nodes,
approaching it as the grid is refined (test_feedrate.py). The time sampling (sampling.py)
therefore checks the sampled references against the limits and re-solves or slows the profile
where the grid was optimistic.

Re-solve with tightened limits (:func:`refine_feed`). Where the sampled references exceed a
limit, the sampler (sampling.resolve_rule) lowers that limit at the feed nodes around the
offending samples (`scales`: per node, a factor on the velocity, acceleration and jerk
limits) and the LP is solved again. The dips it makes keep every (scaled) jerk row, unlike a
slow-down multiplied into b afterwards, whose own jerk overshoots where the jerk limit binds
all along the path (the micromill at F = 1 m/s). Only the nodes within a window around the
tightened ones are free; the others are held at the previous profile, so the rows at the
window's edges take them as boundary conditions, and the first LP's jerk rows are
linearized about the previous profile. The window doubles while that LP is infeasible (the
held neighbours leave no room for the dip), up to the whole grid, where b = 0 is always
feasible. The jerk factor also scales the rest envelope's j_t (its b ~ j_t^(2/3)).

The rows are two-sided (-limit <= row b <= limit: scipy's milp front end to HiGHS, without
integer variables), half the rows of the same LP through linprog's A_ub: ~1.8x faster on the
micromill's 9 axes, the same optimum.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from trajectory.feed_shape import feed_headroom


@dataclass(frozen=True)
class FeedLimits:
    velocity: np.ndarray        # per axis, m/s or rad/s
    acceleration: np.ndarray
    jerk: np.ndarray
    feed: float                 # process feed limit on |dP/dt|, m/s (P is arc length: sdot)

    @classmethod
    def from_machine(cls, machine, feed: float, scale: float = 1.0) -> FeedLimits:
        axes = machine.axes
        return cls(np.array([scale * a.limits.velocity for a in axes]),
                   np.array([scale * a.limits.acceleration for a in axes]),
                   np.array([scale * a.limits.jerk for a in axes]), float(feed))


@dataclass(frozen=True)
class FeedProfile:
    s: np.ndarray               # (N,) arc length, m
    b: np.ndarray               # (N,) sdot^2
    iterations: int

    @property
    def feed(self) -> np.ndarray:
        return np.sqrt(np.maximum(self.b, 0.0))

    def duration(self) -> float:
        """Traversal time: sum of ds over the mean feed of each interval (finite at the
        rest ends, where 1/sdot is not integrable by the plain trapezoid)."""
        f = self.feed
        return float(np.sum(2.0 * np.diff(self.s) / (f[:-1] + f[1:])))


def _difference_operators(n: int, ds: float):
    """Central first and second differences (interior rows 1..n-2) as sparse matrices."""
    rows = np.arange(1, n - 1)
    d1 = sparse.csr_matrix((np.r_[-np.ones(n - 2), np.ones(n - 2)] / (2 * ds),
                            (np.r_[rows - 1, rows - 1], np.r_[rows - 1, rows + 1])), shape=(n - 2, n))
    d2 = sparse.csr_matrix((np.r_[np.ones(n - 2), -2 * np.ones(n - 2), np.ones(n - 2)] / ds**2,
                            (np.r_[rows - 1, rows - 1, rows - 1], np.r_[rows - 1, rows, rows + 1])),
                           shape=(n - 2, n))
    return d1, d2


def jerks(b: np.ndarray, dq, ddq, dddq, ds: float) -> np.ndarray:
    """Axis jerks at the interior grid points for the profile b (exact chain rule)."""
    d1, d2 = _difference_operators(len(b), ds)
    bi = b[1:-1, None]
    return np.sqrt(np.maximum(bi, 0.0)) * (dddq[1:-1] * bi + 1.5 * ddq[1:-1] * (d1 @ b)[:, None]
                                           + 0.5 * dq[1:-1] * (d2 @ b)[:, None])


def _rest_envelope(s, dq, jerk) -> np.ndarray:
    """Upper bound on b from starting and ending at rest with bounded tangential jerk."""
    def envelope(distance, slope):
        with np.errstate(divide='ignore'):
            j_t = np.min(np.where(slope > 0, jerk / slope, np.inf))
        return (0.5 * j_t * (6.0 * distance / j_t) ** (2.0 / 3.0)) ** 2
    return np.minimum(envelope(s - s[0], np.abs(dq[0])), envelope(s[-1] - s, np.abs(dq[-1])))


class _Infeasible(ValueError):
    """The LP has no solution (only possible with held nodes: b = 0 satisfies every row)."""


def _check_grid(s: np.ndarray, limits: FeedLimits) -> None:
    if len(s) < 5 or not np.allclose(np.diff(s), s[1] - s[0], rtol=1e-9, atol=0):
        raise ValueError('the feed grid needs >= 5 uniformly spaced points')
    if limits.feed <= 0:
        raise ValueError(f'process feed limit must be > 0, got {limits.feed}')


def optimize_feed(s, dq, ddq, dddq, limits: FeedLimits, iterations: int = 8,
                  tolerance: float = 1e-3) -> FeedProfile:
    """b(s) on the uniform grid s (N,), with path derivatives dq, ddq, dddq (N, axes)."""
    s = np.asarray(s, float)
    dq, ddq, dddq = (np.asarray(a, float) for a in (dq, ddq, dddq))
    _check_grid(s, limits)
    n = len(s)
    return _solve(s, dq, ddq, dddq, limits, np.ones((n, 3)), np.zeros(n), np.ones(n, bool), False,
                  iterations, tolerance)


def refine_feed(s, b, dq, ddq, dddq, limits: FeedLimits, scales, changed, window: int,
                iterations: int = 8, tolerance: float = 1e-3) -> FeedProfile:
    """The profile b on the uniform grid s re-solved with the limits scaled per node by
    `scales` (N, 3: factors in (0, 1] on velocity (the axes' and the tool's feed F),
    acceleration, jerk), free only within
    `window` nodes of the nodes `changed`, the others held at b (module docstring, "Re-solve
    with tightened limits"); the window doubles while the LP is infeasible."""
    s, b, scales = (np.asarray(a, float) for a in (s, b, scales))
    dq, ddq, dddq = (np.asarray(a, float) for a in (dq, ddq, dddq))
    _check_grid(s, limits)
    n = len(s)
    if scales.shape != (n, 3) or not np.all((scales > 0) & (scales <= 1)):
        raise ValueError(f'limit scales must be ({n}, 3) factors in (0, 1]')
    window = max(int(window), 1)
    while True:
        free = np.zeros(n, bool)
        for m in np.asarray(changed, np.intp):
            free[max(m - window, 0):m + window + 1] = True
        try:
            return _solve(s, dq, ddq, dddq, limits, scales, np.maximum(b, 0.0), free, True,
                          iterations, tolerance)
        except _Infeasible:
            if np.all(free[1:-1]):
                raise
            window *= 2


def _solve(s, dq, ddq, dddq, limits: FeedLimits, scales: np.ndarray, start: np.ndarray,
           free: np.ndarray, warm: bool, iterations: int, tolerance: float) -> FeedProfile:
    """The sequential LP (module docstring) for the nodes `free`, the others held at `start`;
    the jerk rows of the first LP linearized about `start` if `warm`, else left out."""
    n, axes = dq.shape
    ds = s[1] - s[0]
    v_scale, a_scale, j_scale = scales.T

    # velocity and feed: simple upper bounds on b; rest at both ends
    speed = np.abs(dq)
    with np.errstate(divide='ignore'):
        vmax = np.min(np.where(speed > 0, (limits.velocity / speed) ** 2, np.inf), axis=1)
    feed = limits.feed ** 2 * feed_headroom(s)  # F^2 between the nodes too (feed_shape.py)
    upper = np.minimum(np.minimum(vmax, feed) * v_scale ** 2,      # the velocity factor scales the feed too
                       _rest_envelope(s, dq, limits.jerk) * j_scale ** (2.0 / 3.0))
    upper[0] = upper[-1] = 0.0
    free = free | (start > upper)               # a node over its (new) bound cannot be held
    free[0] = free[-1] = False                  # at rest: b = 0
    held = np.where(free, 0.0, np.minimum(start, upper))
    cols = np.flatnonzero(free)

    d1, d2 = _difference_operators(n, ds)
    interior = sparse.eye(n, format='csr')[1:-1]
    rows, rhs = [], []
    for i in range(axes):                       # |q'' b + q'/2 b'| <= a_max
        rows.append(sparse.diags(ddq[1:-1, i]) @ interior + sparse.diags(0.5 * dq[1:-1, i]) @ d1)
        rhs.append(limits.acceleration[i] * a_scale[1:-1])

    from scipy.optimize import Bounds, LinearConstraint, milp   # here: a node that only imports this need not (~0.8 s)
    b = held
    frozen = np.where(free, start, held) if warm else None
    done = 0
    for done in range(1, iterations + 1):
        jerk_rows, jerk_rhs = [], []
        if frozen is not None:
            root = np.sqrt(np.maximum(frozen[1:-1], 0.0))
            for i in range(axes):               # |sqrt(b_hat) (q''' b + 3/2 q'' b' + 1/2 q' b'')| <= j_max
                jerk_rows.append(sparse.diags(root) @ (sparse.diags(dddq[1:-1, i]) @ interior
                                                       + sparse.diags(1.5 * ddq[1:-1, i]) @ d1
                                                       + sparse.diags(0.5 * dq[1:-1, i]) @ d2))
                jerk_rhs.append(limits.jerk[i] * j_scale[1:-1])
        a_all = sparse.vstack(rows + jerk_rows, format='csc')
        limit = np.concatenate(rhs + jerk_rhs)
        offset = a_all @ held                   # the held nodes' share of every row
        a_free = a_all[:, cols].tocsr()
        used = np.diff(a_free.indptr) > 0       # rows with a free node
        if np.any(np.abs(offset[~used]) > limit[~used] * (1.0 + 1e-9)):
            raise _Infeasible('feed optimization failed: held nodes alone exceed a limit')
        result = milp(-np.ones(len(cols)), bounds=Bounds(np.zeros(len(cols)), upper[cols]),
                      constraints=LinearConstraint(a_free[used], (-limit - offset)[used],
                                                   (limit - offset)[used]))
        if result.status in (2, 4):            # infeasible (4: or unbounded, which 0 <= b <= upper is not)
            raise _Infeasible(f'feed optimization failed: {result.message}')
        if result.status != 0:
            raise ValueError(f'feed optimization failed: {result.message}')
        b = held.copy()
        b[cols] = np.maximum(result.x, 0.0)
        if frozen is not None and np.max(np.abs(b - frozen)) <= tolerance * max(np.max(b), 1e-12):
            break
        frozen = b

    worst = np.max(np.abs(jerks(b, dq, ddq, dddq, ds)) / (limits.jerk * j_scale[1:-1, None]))
    if worst > 1.0:
        b = b * worst ** (-2.0 / 3.0)           # jerk ~ b^(3/2): scale onto the limit
    return FeedProfile(s, b, done)
