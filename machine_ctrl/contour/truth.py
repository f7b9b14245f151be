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
Compiled (numba) per step, each step's arithmetic as numpy's vectorized form of it (the
bits of the earlier vectorized version); the Hermite path between 1 kHz samples of a
50 mm/s, 30 mm radius path is exact to ~1e-15 m.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from machine_ctrl.contour.estimation import ToolTrajectory, hermite

GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
ITERATIONS = 80               # bracket 2 steps wide -> 2 * 0.618^80 ~ 4e-17 steps


def _path(values, slopes, period, s, normalize):
    """Points of the Hermite path at fractional sample indices s."""
    i = np.minimum(np.floor(s).astype(int), len(values) - 2)
    u = (s - i)[:, None]
    points = hermite(values[i], slopes[i], values[i + 1], slopes[i + 1], u, period)
    return points / np.linalg.norm(points, axis=1)[:, None] if normalize else points


@njit(cache=True)
def nearest_samples(values, actual, step_of, window):
    """For each row k of `actual`: the index of the sample of `values` nearest to it (least
    squared distance, the first one on a tie) among samples step_of[k] - window ..
    step_of[k] + window, clipped to the path (steps past step_of's end use its last entry).
    Compiled: the search is O(steps x window), ~25x faster than numpy's gathered arrays."""
    n, m, dims = values.shape[0], actual.shape[0], values.shape[1]
    last = step_of.shape[0] - 1
    nearest = np.empty(m, np.int64)
    for k in range(m):
        centre = step_of[min(k, last)]
        best, best_index = np.inf, -1
        for offset in range(-window, window + 1):
            c = min(max(centre + offset, 0), n - 1)
            distance = 0.0
            for j in range(dims):
                distance += (values[c, j] - actual[k, j]) ** 2
            if best_index < 0 or distance < best:
                best, best_index = distance, c
        nearest[k] = best_index
    return nearest


@njit(cache=True)
def _squared_distance(values, slopes, period, s, normalize, actual, k):
    """|path(s) - actual[k]|^2, the path as :func:`_path` evaluates it (the same operations,
    in the same order: the same bits)."""
    i = min(int(math.floor(s)), values.shape[0] - 2)
    u = s - i
    u2 = u * u
    u3 = u2 * u
    dims = values.shape[1]
    point = np.empty(dims)
    for j in range(dims):          # estimation.hermite
        point[j] = ((2 * u3 - 3 * u2 + 1) * values[i, j] + (u3 - 2 * u2 + u) * period * slopes[i, j]
                    + (-2 * u3 + 3 * u2) * values[i + 1, j] + (u3 - u2) * period * slopes[i + 1, j])
    if normalize:
        norm = 0.0
        for j in range(dims):
            norm += point[j] * point[j]
        norm = math.sqrt(norm)
        for j in range(dims):
            point[j] = point[j] / norm
    distance = 0.0
    for j in range(dims):
        distance += (point[j] - actual[k, j]) ** 2
    return distance


@njit(cache=True)
def golden_section(values, slopes, period, actual, nearest, normalize):
    """For each row k of `actual`: the fractional sample index s in [nearest[k] - 1,
    nearest[k] + 1] (within the path) where the path comes closest, by ITERATIONS steps of
    golden-section search."""
    n, m = values.shape[0], actual.shape[0]
    s = np.empty(m)
    for k in range(m):
        lo, hi = max(nearest[k] - 1.0, 0.0), min(nearest[k] + 1.0, n - 1.0)
        a, b = hi - GOLDEN * (hi - lo), lo + GOLDEN * (hi - lo)
        fa = _squared_distance(values, slopes, period, a, normalize, actual, k)
        fb = _squared_distance(values, slopes, period, b, normalize, actual, k)
        for _ in range(ITERATIONS):
            if fa < fb:
                hi = b
            else:
                lo = a
            a, b = hi - GOLDEN * (hi - lo), lo + GOLDEN * (hi - lo)
            fa = _squared_distance(values, slopes, period, a, normalize, actual, k)
            fb = _squared_distance(values, slopes, period, b, normalize, actual, k)
        s[k] = (lo + hi) / 2.0
    return s


def closest_points(values, slopes, period, actual, window, normalize=False):
    """(s, closest point) for each row k of `actual`, searched on the path through `values`
    (rows = steps, slopes = their time derivatives) within +-window samples of step k's;
    repeated samples (the reference at rest) count once, s indexes the remaining ones."""
    keep = np.concatenate(([True], (np.diff(values, axis=0) != 0.0).any(axis=1)))
    values, slopes = values[keep], slopes[keep]       # a stop is one point of the path, not many
    window = window + int(np.count_nonzero(~keep))     # ... so the window keeps its reach in steps
    step_of = np.cumsum(keep) - 1                      # sample index of each step
    if len(values) == 1:
        return np.zeros(len(actual)), np.repeat(values[:1], len(actual), axis=0)
    actual = np.ascontiguousarray(actual, float)
    nearest = nearest_samples(values, actual, step_of, window)
    s = golden_section(values, slopes, period, actual, nearest, normalize)
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
