"""The "true" contour errors, by searching the reference path for the point closest to the
actual one (Sencer section 4, after Erkorkmaz & Altintas [5]): the slow reference
implementation the real-time estimators of :mod:`machine_ctrl.contour.estimation` are measured against.

For every step k: the nearest reference sample within +-`window` steps of k, then a
golden-section search on the cubic Hermite path (positions and their exact time
derivatives, :func:`machine_ctrl.contour.estimation.hermite`) over the two sample intervals around it.
The tool-tip path is P_ref(s); the orientation path is O_ref(s)/|O_ref(s)| on the unit
sphere (Sencer: "the closest normal point to the actual reference orientation tool-path in
spherical coordinates"), where the closest chord is the closest angle. Errors point from
the actual value to the closest path point (the sign of e = ref - actual, Eq. 15).
Vectorized over all steps; the Hermite path between 1 kHz samples of a 50 mm/s, 30 mm
radius path is exact to ~1e-15 m.
"""
from __future__ import annotations

import math

import numpy as np

from machine_ctrl.contour.estimation import ToolTrajectory, hermite

GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
ITERATIONS = 80               # bracket 2 steps wide -> 2 * 0.618^80 ~ 4e-17 steps
BLOCK = 2000                  # steps per block of the coarse search (memory)


def _path(values, slopes, period, s, normalize):
    """Points of the Hermite path at fractional sample indices s."""
    i = np.minimum(np.floor(s).astype(int), len(values) - 2)
    u = (s - i)[:, None]
    points = hermite(values[i], slopes[i], values[i + 1], slopes[i + 1], u, period)
    return points / np.linalg.norm(points, axis=1)[:, None] if normalize else points


def closest_points(values, slopes, period, actual, window, normalize=False):
    """(s, closest point) for each row k of `actual`, searched on the path through `values`
    (rows = steps, slopes = their time derivatives) within +-window samples of step k's;
    repeated samples (the reference at rest) count once, s indexes the remaining ones."""
    keep = np.concatenate(([True], (np.diff(values, axis=0) != 0.0).any(axis=1)))
    values, slopes = values[keep], slopes[keep]       # a stop is one point of the path, not many
    window = window + int(np.count_nonzero(~keep))     # ... so the window keeps its reach in steps
    step_of = np.cumsum(keep) - 1                      # sample index of each step
    n, m = len(values), len(actual)
    offsets = np.arange(-window, window + 1)
    nearest = np.empty(m, int)
    for start in range(0, m, BLOCK):
        k = np.arange(start, min(start + BLOCK, m))
        candidates = np.clip(step_of[np.minimum(k, len(step_of) - 1)][:, None] + offsets, 0, n - 1)
        distance = ((values[candidates] - actual[k, None, :]) ** 2).sum(axis=2)
        nearest[k] = candidates[np.arange(len(k)), distance.argmin(axis=1)]
    if n == 1:
        return np.zeros(m), np.repeat(values[:1], m, axis=0)
    lo = np.maximum(nearest - 1.0, 0.0)
    hi = np.minimum(nearest + 1.0, n - 1.0)

    def cost(s):
        return ((_path(values, slopes, period, s, normalize) - actual) ** 2).sum(axis=1)

    a, b = hi - GOLDEN * (hi - lo), lo + GOLDEN * (hi - lo)
    fa, fb = cost(a), cost(b)
    for _ in range(ITERATIONS):
        left = fa < fb
        hi = np.where(left, b, hi)
        lo = np.where(left, lo, a)
        a, b = hi - GOLDEN * (hi - lo), lo + GOLDEN * (hi - lo)
        fa, fb = cost(a), cost(b)
    s = (lo + hi) / 2.0
    return s, _path(values, slopes, period, s, normalize)


def true_tool_tip_errors(trajectory: ToolTrajectory, p_actual, window: int = 200):
    """True tool-tip contour error vectors (m) for actual tool tips p_actual[k] at steps
    trajectory.first + k."""
    s, closest = closest_points(trajectory.rows[0], trajectory.rows[1], trajectory.period,
                                np.asarray(p_actual, float), window)
    return closest - p_actual


def true_orientation_errors(trajectory: ToolTrajectory, o_actual, window: int = 200):
    """True orientation contour error vectors (chord from the actual tool axis to the
    closest reference tool axis, ~rad) for o_actual[k] at steps trajectory.first + k."""
    s, closest = closest_points(trajectory.rows[3], trajectory.rows[4], trajectory.period,
                                np.asarray(o_actual, float), window, normalize=True)
    return closest - o_actual
