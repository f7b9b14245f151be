"""When a real-time contour-error estimate can be trusted, and how far: for every step a bound
on |estimate - true contour error| from the reference path's own geometry near the estimate,
and validity = that bound within a tolerance (README "Contour error", "Validity"). No ROS;
:mod:`machine_ctrl.contour.estimation` calls it once per step and path.

**The bound.** Every estimator of :mod:`machine_ctrl.contour.estimation` returns the distance
vector from the actual point P to a line: through a path point C with the unit direction T of
the path at a path point (basic: C = P_ref(t), T its tangent; shifted: C = P_ref(t), T the
tangent at t - t_d; compensated: C = P_ref(t - t_d), T its tangent; the rest rule: C = the rest
point, T the last or first direction of travel; orientation, Eq. 28: the same on the tool-axis
path O_ref(t), T = W/|W|). Let F be the path point closest to P, eps = F - P the true contour
error, d = |eps|, Theta the largest angle between T and the path's tangents over an arc holding
F, C and T's point (at most the path's total turning there plus the angle from T to one of its
rows' directions). As T_F . eps = 0 at an interior closest point,

    est - eps = (I - T T^T)(C - F) - T (T . eps),   |(I - T T^T)(C - F)| <= a Theta,
    |T . eps| = |(T - T_F) . eps| <= Theta d,

a = the arc from F to C. a is not known, but the tangential residual r = T . (C - P) (Eq. 19's
e_t for basic) is, and a cos Theta <= |r| + Theta d. With d <= |est| + bound:

    bound = Theta (|r| / c + Theta_w |est| / c + |est|) / (1 - Theta - Theta Theta_w / c),
    c = cos Theta_w,

Theta_w >= Theta the turning over the whole window (below). To first order Theta (|r| + |est|):
on a circle of curvature kappa with the basic estimator about kappa r (|r| + d) against its
actual error kappa r^2 / 2. Always |eps| <= |e| (P_ref(t) is on the path), so |est - eps| <=
|est| + |e| (the *plain* bound); the bound is the smaller one, plus BOUND_FLOOR.

**Theta** is summed from the rows: the angles between successive directions of motion, across
rests (a rest between two motions counts the angle between the direction it arrived in and the
one it leaves in: the 145 deg of the micromill's approach -> helix join, 180 deg at a
reversal), plus each direction's error (RATE_ROUNDING / |V| + DIRECTION_TRUNCATION), so the
last rows of a stop, where |V| -> 0, count for much by themselves. Cumulative per row
(:class:`PathGeometry`), so a window costs two binary searches.

**The window** is where F can be (a within [r - Theta d, (r + Theta d) / cos Theta], Theta <=
MAX_TURN, d <= |est| + tol) widened by 2.5 (|est| + tol), within which any other path point
closer to P than F must lie (2 (d + bound) of chord, 2.3 of arc at MAX_TURN), and holding C
and T's point. Theta_w > MAX_TURN (a corner, a reversal, a join, a stop's last rows in it):
the plain bound. The window is looked for in the rows within `horizon` steps of the step
(HORIZON both ways; the node keeps as many behind, the trajectory streams further ahead, so
the node computes what the offline run computes); one that runs past them while the path
still moves there gets the plain bound ('horizon'). A rest lasting past them is an end of the
path (or its start). A path that comes back within 2 d of P from beyond the window (a helix
whose pitch is under twice the error, a motion resumed after a longer rest) is outside any
local estimator, and outside this bound.

**Ends and corners.** A P beyond the end of the path (behind its start) has the end point as
its closest point, which no tangent line gives: a line's estimate gets the plain bound ('end',
'start'). The tool-tip estimators then use the end point itself where it is certainly the
closest (:func:`beyond_end`, moving steps; the orientation estimate keeps the plain bound), and
the rest rule its own "all of e counts" (at rest), both exact up to how far the Hermite path's
last interval reaches past the rest point (:func:`excursion`). The rest rule at a corner
(:func:`corner_check`): the path leaving the rest point Q along T_out, turning by at most
Theta_out, gets no closer to P than |Q - P| while T_out . (P - Q) <= -Theta_out |Q - P|; then
the estimate is bounded on the arriving side alone, so a tool settling behind the corner keeps
valid estimates through a dwell.

A long rest keeps the path it ended (:class:`PathMemory`): the rows of the last `horizon` steps
of motion are copied when the reference comes to rest, so a step of the rest, or of the motion
that follows it, still sees the path that led to the rest point (and its corner).

**Validity**: bound <= Tolerance: max(absolute, BOUND_REL |est|) (:func:`machine_tolerances`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

# assumed: below this the reference counts as at rest (1 nm/s; 1 nrad/s for the tool axis).
SPEED_TOL = 1e-9            # m/s (and 1/s for the tool-axis rate)
# assumed: the error of the directions V/|V|, W/|W| of tool_reference's rows: its rounding,
# eps |x| / (2h) (5.5e-12 1/s for the unit tool axis, 2.8e-13 m/s for |P| <= 0.05 m), doubled, over
# |V|, plus 1e-8 rad for its O(h^2) truncation (1e-11 m/s at 10 mm/s there, 1e-9 relative, x10).
RATE_ROUNDING = 1e-11       # m/s (1/s)
DIRECTION_TRUNCATION = 1e-8  # rad
# assumed: beyond 0.5 rad of turning within the window the expansion above is not used (a join,
# a corner, a reversal, the last rows of a stop): the step gets the plain bound.
MAX_TURN = 0.5              # rad
COS_MAX_TURN = math.cos(MAX_TURN)
# The bound's floor: the numerical resolution of the estimates against the closest-point truth
# (measured: <= 1e-12 m, rad on both machines; x10).
BOUND_FLOOR = 1e-11         # m (rad)
# Validity: bound <= max(absolute, BOUND_REL |est|). assumed: 25 % of the estimate, or half the
# finest sensor resolution of the machine's linear (tool tip) / rotary (tool axis) axes: an
# estimate that close to the truth is as good as the measurement it comes from
# (:func:`machine_tolerances`; 10 nm / 10 nrad without a machine).
BOUND_ABS = 1e-8            # m (rad)
BOUND_REL = 0.25


@dataclass(frozen=True)
class Tolerance:
    """The largest bound of a valid estimate: max(absolute, relative |est|)."""
    absolute: float = BOUND_ABS
    relative: float = BOUND_REL

    def __call__(self, magnitude: float) -> float:
        return max(self.absolute, self.relative * magnitude)


def machine_tolerances(machine) -> tuple[Tolerance, Tolerance]:
    """(tool tip, tool axis) tolerances of a MachineConfig: half the finest sensor resolution
    of its linear / rotary axes (the default where it has none)."""
    def half_finest(kind):
        resolutions = [a.sensor_resolution for a in machine.axes if a.kind == kind and a.sensor_resolution > 0]
        return Tolerance(0.5 * min(resolutions)) if resolutions else Tolerance()
    return half_finest('linear'), half_finest('rotary')


class Check(NamedTuple):
    """The bound on |estimate - true contour error| (m, or rad for the tool axis) of one step,
    whether it is within the tolerance, and if not why (README "Validity")."""
    bound: float
    valid: bool
    reason: str = ''     # '' when valid; else turn, horizon, end, start, bound


class PathGeometry:
    """Per held row of one reference path (the tool tip: rows P, V; the tool axis: O, W): arc
    length `s` (cumulative chord), cumulative turning `phi` (angles between successive
    directions of motion, across rests, plus the error of each direction), `moving` (|V| above
    SPEED_TOL), and the last direction of motion up to the row (`last`, NaN before any) with
    its noise, from which the next chunk continues. Chunks continue with exactly the
    additions of one whole array (bit for bit, tested), so the node's rows equal the offline's."""

    def __init__(self):
        self.s = np.empty(0)
        self.phi = np.empty(0)
        self.moving = np.empty(0, bool)
        self.last = np.empty((0, 3))
        self.last_noise = np.empty(0)

    def replace_from(self, index: int, x, rate, x_before) -> None:
        """Rows from `index` on are the chunk (x, rate); x_before: the row before it (None: the
        chunk starts the path)."""
        x, rate = np.asarray(x, float), np.asarray(rate, float)
        m = len(x)
        if x_before is None or index == 0:
            s0, phi0, last0, noise0 = 0.0, 0.0, np.full(3, np.nan), np.nan
            chords = np.concatenate(([0.0], np.sqrt((np.diff(x, axis=0) ** 2).sum(axis=1))))
        else:
            s0, phi0, last0, noise0 = self.s[index - 1], self.phi[index - 1], self.last[index - 1], self.last_noise[index - 1]
            chords = np.sqrt((np.diff(np.vstack((x_before, x)), axis=0) ** 2).sum(axis=1))
        speed = np.sqrt((rate * rate).sum(axis=1))
        moving = speed > SPEED_TOL
        safe = np.where(moving, speed, 1.0)
        direction = np.where(moving[:, None], rate / safe[:, None], np.nan)
        noise = np.where(moving, RATE_ROUNDING / safe + DIRECTION_TRUNCATION, np.nan)
        latest = np.where(moving, np.arange(m), -1)
        np.maximum.accumulate(latest, out=latest)
        last = np.where((latest >= 0)[:, None], direction[np.maximum(latest, 0)], last0)
        last_noise = np.where(latest >= 0, noise[np.maximum(latest, 0)], noise0)
        before = np.vstack((last0[None], last[:-1]))
        before_noise = np.concatenate(([noise0], last_noise[:-1]))
        with np.errstate(invalid='ignore'):
            angle = np.arctan2(np.sqrt((np.cross(before, direction) ** 2).sum(axis=1)), (before * direction).sum(axis=1))
            turn = np.where(np.isnan(before_noise), 0.0, angle + before_noise)
        increment = np.where(moving, turn + noise, 0.0)
        s = np.cumsum(np.concatenate(([s0], chords)))[1:] if x_before is not None and index else np.cumsum(chords)
        phi = np.cumsum(np.concatenate(([phi0], increment)))[1:]
        self.s = np.concatenate((self.s[:index], s))
        self.phi = np.concatenate((self.phi[:index], phi))
        self.moving = np.concatenate((self.moving[:index], moving))
        self.last = np.concatenate((self.last[:index], last))
        self.last_noise = np.concatenate((self.last_noise[:index], last_noise))

    def drop(self, cut: int) -> None:
        self.s, self.phi, self.moving = self.s[cut:], self.phi[cut:], self.moving[cut:]
        self.last, self.last_noise = self.last[cut:], self.last_noise[cut:]

    def arc(self, index: float) -> float:
        """s at a fractional row index (clamped into the rows), linear between rows."""
        n = len(self.s)
        index = min(max(index, 0.0), n - 1.0)
        i = min(int(index), n - 2) if n > 1 else 0
        u = index - i
        return float(self.s[i]) if u == 0.0 else float(self.s[i] + u * (self.s[i + 1] - self.s[i]))


@dataclass(frozen=True)
class Snapshot:
    """s, phi and moving of the rows before a rest began (the last `horizon` steps of motion,
    from step `first`), and how far the path can reach beyond the rest point in its last
    interval (the Hermite path from the last moving row: |chord| + 4/27 h |V|)."""
    first: int
    s: np.ndarray
    phi: np.ndarray
    moving: np.ndarray
    excursion: float

    def rows_until(self, step: int, s: float, phi: float, moving: bool) -> int | None:
        """How many of its rows lead to a held row at `step` with these s, phi (the same
        path: both only grow with motion), or None."""
        i = step - self.first
        if 0 <= i < len(self.s) and self.s[i] == s and self.phi[i] == phi:
            return i + 1
        if not moving and self.s[-1] == s and self.phi[-1] == phi:       # later in the same rest
            return len(self.s)
        return None

    def ends_at(self, s: float, phi: float) -> bool:
        """The rest this snapshot led to is the one at a row with these s, phi."""
        return bool(self.s[-1] == s and self.phi[-1] == phi)


class PathMemory:
    """What one estimator remembers of one path (tool tip or tool axis) to bound its estimates:
    the rows that led to the current rest (:class:`Snapshot`), taken on its first step."""

    def __init__(self, kind: int):
        self.kind = kind                     # 0: tool tip, 1: tool axis (ToolTrajectory.geometry)
        self.before: Snapshot | None = None
        self._moving = False

    def note(self, trajectory, step: int) -> None:
        """Step `step` is being estimated (steps in order): keep the path's last motion when the
        reference comes to rest."""
        g = trajectory.geometry[self.kind]
        i = step - trajectory.first
        moving = bool(g.moving[i])
        if self._moving and not moving and i > 0:
            a = max(i - trajectory.horizon, 0)
            self.before = Snapshot(trajectory.first + a, g.s[a:i + 1].copy(), g.phi[a:i + 1].copy(),
                                   g.moving[a:i + 1].copy(), excursion(trajectory, self.kind, i - 1, i))
        self._moving = moving

    def window(self, trajectory, step: int, lo: float, hi: float, until: int | None = None):
        """(Theta, start, end) over the held rows whose arcs cover (lo, hi), within `horizon` steps
        of `step` (ahead: of `until` if given): Theta in rad, corners and direction errors
        included; start / end: the index (into the held rows) of a path start / end the window
        reaches (a rest lasting past the rows looked at), else None. None when the window runs
        past those rows while the path moves there."""
        span = self._span(trajectory, step, lo, hi, until)
        if span is None:
            return None
        phi0, i1, start, end = span
        return float(trajectory.geometry[self.kind].phi[i1] - phi0), start, end

    def corner(self, trajectory, step: int, lo: float, hi: float, s_q: float, until: int | None = None):
        """The window split at the rest at arc s_q (a corner): (Theta before it, Theta after it,
        direction arriving, direction leaving, index of the rest's last row, index of the first
        row after it), or None when the window runs past the rows or the path goes on from s_q
        only beyond the window."""
        span = self._span(trajectory, step, lo, hi, until)
        if span is None:
            return None
        phi0, i1, _, _ = span
        g = trajectory.geometry[self.kind]
        leaving = int(g.s.searchsorted(s_q, 'right'))      # the first row past the rest point
        rest = leaving - 1
        if leaving > i1 or rest < 0 or g.moving[rest]:
            return None
        return (float(g.phi[rest] - phi0), float(g.phi[i1] - g.phi[leaving]), g.last[rest].tolist(),
                g.last[leaving].tolist(), rest, leaving)

    def _span(self, trajectory, step: int, lo: float, hi: float, until: int | None):
        """(phi before the window, index of its last row, start, end) (see window)."""
        g = trajectory.geometry[self.kind]
        first, h, s = trajectory.first, trajectory.horizon, g.s
        a = max(step - h - first, 0)
        b = min((step if until is None else until) + h - first, len(s) - 1)
        i1 = int(s.searchsorted(hi, 'right'))              # first row beyond hi (s only grows)
        end = None
        if i1 > b:
            if g.moving[b]:
                return None
            i1 = end = b                                    # a rest to the horizon: the path ends there
        i0 = int(s.searchsorted(lo, 'left')) - 1            # last row before lo
        start = None
        if i0 >= a:
            phi0 = g.phi[i0]
        else:
            moving = bool(g.moving[a])
            known = None if self.before is None else self.before.rows_until(first + a, s[a], g.phi[a], moving)
            if known is not None:                           # the path that led to the rest, before the rows
                j0 = int(self.before.s[:known].searchsorted(lo, 'left')) - 1
                if j0 < 0:
                    return None
                phi0 = self.before.phi[j0]
            elif moving:
                return None
            else:
                phi0, start = g.phi[a], a                   # nothing before the rest: the path starts there
        return phi0, i1, start, end


def excursion(trajectory, kind: int, moving: int, rest: int) -> float:
    """How far the Hermite path between a moving row and a rest row (indices into the held rows)
    can reach from the rest point: |chord| + 4/27 h |V| (max of the Hermite basis term)."""
    position, rate = (0, 1) if kind == 0 else (3, 4)
    x, v = trajectory.rows[position], trajectory.rows[rate]
    return float(np.sqrt(((x[moving] - x[rest]) ** 2).sum()) + 4.0 / 27.0 * trajectory.period
                 * np.sqrt((v[moving] ** 2).sum()))


def line_bound(turn: float, near: float, residual: float, magnitude: float) -> float:
    """The module docstring's bound: `turn` over the wide window (<= MAX_TURN), `near` over the
    arc holding F, C and T's point, the tangential residual r and |est|."""
    c = math.cos(turn)
    return near * (abs(residual) / c + turn * magnitude / c + magnitude) / (1.0 - near - near * turn / c)


def dot(a, b) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def angle(u, v) -> float:
    """Angle between unit 3-vectors (floats), robust near 0 and pi."""
    cx, cy, cz = u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]
    return math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), u[0] * v[0] + u[1] * v[1] + u[2] * v[2])


# --- the checks, one per kind of estimate -----------------------------------------------------------

def nearer_row_angle(geometry: PathGeometry, direction, index: float) -> float:
    """Angle from a direction interpolated at a fractional row index to the direction of row
    int(index), or of the next row when that is much closer (or the row has none: NaN)."""
    j = int(index)
    turn = angle(direction, geometry.last[j].tolist())
    if not turn <= 0.1 * MAX_TURN and j + 1 < len(geometry.s):
        ahead = angle(direction, geometry.last[j + 1].tolist())
        if ahead <= turn or turn != turn:
            turn = ahead
    return turn


def norm(x) -> float:
    return math.sqrt(dot(x, x))


def _plain(plain: float, tol: float, reason: str) -> Check:
    plain += BOUND_FLOOR
    return Check(plain, plain <= tol, '' if plain <= tol else reason)


def foot_window(residual: float, magnitude: float, tol: float, s_c: float, s_t: float) -> tuple[float, float]:
    """The arc window of a line check (module validity): where the closest point F can be (a
    = arc F -> C within [r - Theta d, (r + Theta d) / cos Theta], Theta <= MAX_TURN, d <= |est| +
    tol), widened by the 2.5 (|est| + tol) within which another path point could be closer to P
    than F, and holding C and T's point."""
    spread, c = MAX_TURN * (magnitude + tol), COS_MAX_TURN
    a_lo, a_hi = residual - spread, residual + spread
    a_lo, a_hi = min(a_lo, a_lo / c), max(a_hi, a_hi / c)
    around = 2.5 * (magnitude + tol)
    return min(s_c - a_hi - around, s_c, s_t), max(s_c - a_lo + around, s_c, s_t)


def line_check(memory: PathMemory, tolerance: Tolerance, trajectory, step: int, est, e,
               residual: float, s_c: float, s_t: float, turn_t: float, point, until: int | None = None) -> Check:
    """The bound of an estimate `est` = the distance from the actual `point` to the line
    through the path point at arc s_c with the direction T of the path at arc s_t (module
    validity): `residual` = T . (C - point), `turn_t` = angle from T to the direction of a
    row in the window; e = P_ref(step) - point; `until`: see PathMemory.window. The bound
    over the whole window, made tighter over the arc holding F, C and T's point when that
    one is above the tolerance."""
    magnitude = norm(est)
    plain, tol = magnitude + norm(e), max(tolerance.absolute, tolerance.relative * magnitude)
    lo, hi = (s_c, s_t) if s_c <= s_t else (s_t, s_c)
    window = memory.window(trajectory, step, *foot_window(residual, magnitude, tol, s_c, s_t), until)
    if window is None:
        return _plain(plain, tol, 'horizon')
    turn, start, end = window
    turn += turn_t
    if not turn <= MAX_TURN:                          # NaN too: no direction to compare with
        return _plain(plain, tol, 'turn')
    if end is not None or start is not None:
        problem = _beyond_ends(memory, trajectory, step, start, end, point, until)
        if problem:
            return _plain(plain, tol, problem)
    bound = min(line_bound(turn, turn, residual, magnitude), plain) + BOUND_FLOOR
    if bound > tol:
        # the closest point F is a = (signed arc F -> C) before C, a within [r - Theta d, (r + Theta d) / cos Theta]
        c, spread = math.cos(turn), turn * (magnitude + tol)
        a_lo, a_hi = residual - spread, residual + spread
        a_lo, a_hi = min(a_lo, a_lo / c), max(a_hi, a_hi / c)
        near = memory.window(trajectory, step, min(s_c - a_hi, lo), max(s_c - a_lo, hi), until)
        if near is not None:
            bound = min(line_bound(turn, near[0] + turn_t, residual, magnitude), plain) + BOUND_FLOOR
    return Check(bound, bound <= tol, '' if bound <= tol else 'bound')


def _beyond_ends(memory: PathMemory, trajectory, step: int, start, end, point, until) -> str:
    """'end' when `point` is beyond the path end the window reached (its end point is then
    closest, which no tangent line gives), 'start' when behind its start, else ''."""
    geometry = trajectory.geometry[memory.kind]
    position = 0 if memory.kind == 0 else 3
    if end is not None:
        q = trajectory.rows[position, end]
        if dot(geometry.last[end], [point[i] - q[i] for i in range(3)]) > 0.0:
            return 'end'
    if start is not None:
        last = min((step if until is None else until) + trajectory.horizon, trajectory.end - 1) - trajectory.first
        moving = geometry.moving[start:last + 1]
        if moving.any():
            q = trajectory.rows[position, start]
            if dot(geometry.last[start + int(moving.argmax())], [q[i] - point[i] for i in range(3)]) > 0.0:
                return 'start'
    return ''


def beyond_end(memory: PathMemory, tolerance: Tolerance, trajectory, step: int, point, e, which: str):
    """The estimate for a moving step whose point P is beyond the path's end (which == 'end':
    the reference comes to rest within the horizon) or behind its start ('start'), as
    :func:`line_check` found it, and its bound: (est = Q - P, Check), Q the end (start) point,
    or None when Q is not certainly the closest point.

    Q is the closest point of the path within the window when P lies beyond it along the
    path's direction T there, s = T . (P - Q) > 0 (T . (Q - P) > 0 behind the start), and the
    turning Theta over the window holds |s| cos Theta >= n sin Theta, n the part of P - Q normal
    to T: a path point x at arc u from Q has |P - x|^2 - |P - Q|^2 >= u^2 cos^2 Theta +
    2 u (|s| cos Theta - n sin Theta) > 0, so within 2 |P - Q| / cos Theta of arc (the window,
    2.5 x) none is closer. Exact up to how far the Hermite path's last (first) interval reaches
    past Q (:func:`excursion`). An end is a rest lasting past the horizon; a motion resumed later
    (a dwell longer than HORIZON) is not seen, as for the rest rule (module docstring: outside
    this bound), so that the node, which holds the rows to the horizon, computes what the
    offline run computes."""
    g, h, first = trajectory.geometry[memory.kind], trajectory.horizon, trajectory.first
    position = 0 if memory.kind == 0 else 3
    if which == 'end':
        q_row = min(step + h - first, len(g.s) - 1)
        if g.moving[q_row]:
            return None
        direction, sign = g.last[q_row].tolist(), 1.0
    else:
        q_row = max(step - h - first, 0)
        moving = g.moving[q_row:min(step + h, trajectory.end - 1) - first + 1]
        if g.moving[q_row] or not moving.any():
            return None
        leaving = q_row + int(moving.argmax())
        direction, sign = g.last[leaving].tolist(), -1.0
    q = trajectory.rows[position, q_row]
    est = [q[i] - point[i] for i in range(3)]
    magnitude = norm(est)
    plain, tol = magnitude + norm(e), tolerance(magnitude)
    reach, s_q = 2.5 * (magnitude + tol) / COS_MAX_TURN, float(g.s[q_row])
    window = memory.window(trajectory, step, *((s_q - reach, s_q) if which == 'end' else (s_q, s_q + reach)))
    if window is None or (window[2] if which == 'end' else window[1]) is None or not window[0] <= MAX_TURN:
        return None
    along = -sign * dot(direction, est)                   # |s| when P is beyond Q
    normal = math.sqrt(max(magnitude * magnitude - along * along, 0.0))
    if not (along > 0.0 and along * math.cos(window[0]) >= normal * math.sin(window[0])):
        return None
    past = _excursion_in(memory, trajectory, q_row) if which == 'end' else excursion(trajectory, memory.kind,
                                                                                       leaving, q_row)
    if past is None:
        return None
    bound = min(past, plain) + BOUND_FLOOR
    return est, Check(bound, bound <= tol, '' if bound <= tol else 'bound')


def rest_check(memory: PathMemory, tolerance: Tolerance, trajectory, step: int, est, e, direction,
               beyond: bool, ahead: int | None, point) -> Check:
    """The bound of the rest rule's estimate (:class:`RestDirection`) at a step where the
    reference is at rest. A direction from the first motion ahead (before the path starts)
    looks `horizon` steps past that motion's first step, however far ahead it is."""
    magnitude = norm(est)
    plain, tol = magnitude + norm(e), tolerance(magnitude)
    geometry = trajectory.geometry[memory.kind]
    i = step - trajectory.first
    s_q = float(geometry.s[i])
    if direction is None:                 # no motion known: the path is the rest point, est = e
        reach = 2.5 * (magnitude + tol)
        window = memory.window(trajectory, step, s_q - reach, s_q + reach)
        alone = window is not None and window[1] is not None and window[2] is not None
        return Check(BOUND_FLOOR, True) if alone else _plain(plain, tol, 'horizon')
    turn_t = 0.0 if ahead is not None else angle(direction, geometry.last[i].tolist())   # ahead: that row's own
    if not beyond:
        check = line_check(memory, tolerance, trajectory, step, est, e, dot(direction, e), s_q, s_q, turn_t, point,
                           ahead)
        if check.valid or check.reason != 'turn' or ahead is not None:
            return check
        return corner_check(memory, tolerance, trajectory, step, est, e, direction, turn_t, point, False) or check
    # all of e: exact when the path ends (starts) at the rest point, within MAX_TURN of turning,
    # up to how far the path's last (first) interval reaches past the rest point
    reach = 2.5 * (magnitude + tol)
    window = memory.window(trajectory, step, s_q - reach, s_q + reach, ahead)
    if window is None:
        return _plain(plain, tol, 'horizon')
    if ahead is None and (window[0] + turn_t > MAX_TURN or window[2] is None):     # the path goes on from here
        return corner_check(memory, tolerance, trajectory, step, est, e, direction, turn_t, point, True) or \
            _plain(plain, tol, 'turn' if window[0] + turn_t > MAX_TURN else 'end')
    if not window[0] + turn_t <= MAX_TURN:
        return _plain(plain, tol, 'turn')
    if ahead is not None:
        if window[1] is None:
            return _plain(plain, tol, 'start')
        reach = excursion(trajectory, memory.kind, ahead - trajectory.first, i)
    else:
        reach = _excursion_in(memory, trajectory, i)
        if reach is None:
            return _plain(plain, tol, 'end')
    bound = min(reach, plain) + BOUND_FLOOR
    return Check(bound, bound <= tol, '' if bound <= tol else 'bound')


def _excursion_in(memory: PathMemory, trajectory, i: int) -> float | None:
    """How far the interval arriving at the rest at held row i reaches past the rest point
    (from the rows, or from the memory of the rest when they are gone), or None."""
    geometry = trajectory.geometry[memory.kind]
    arriving = int(geometry.s.searchsorted(geometry.s[i], 'left')) - 1      # the last row before the rest point
    if arriving >= max(i - trajectory.horizon, 0) and geometry.moving[arriving]:
        return excursion(trajectory, memory.kind, arriving, i)
    if memory.before is not None and memory.before.ends_at(geometry.s[i], geometry.phi[i]):
        return memory.before.excursion
    return None


def corner_check(memory: PathMemory, tolerance: Tolerance, trajectory, step: int, est, e,
                 direction, turn_t: float, point, beyond: bool) -> Check | None:
    """The rest rule at a corner (the reference at rest where the path turns by more than
    MAX_TURN, the direction used: the one it arrived in). The path leaving the rest point Q
    along T_out and turning by at most Theta_out gets no closer to P than |Q - P| while
    T_out . (P - Q) <= -Theta_out |Q - P|; then the estimate is bounded on the arriving side
    alone (or, beyond its end, Q is the closest point). None when that does not hold."""
    magnitude = norm(est)
    plain, tol = magnitude + norm(e), tolerance(magnitude)
    geometry = trajectory.geometry[memory.kind]
    i = step - trajectory.first
    s_q = float(geometry.s[i])
    residual = dot(direction, e)
    split = memory.corner(trajectory, step, *foot_window(residual, magnitude, tol, s_q, s_q), s_q)
    if split is None:
        return None
    arriving, leaving, _, t_out, rest, after = split
    arriving += turn_t
    q = trajectory.rows[0 if memory.kind == 0 else 3, i]
    away = [point[j] - q[j] for j in range(3)]
    if not (arriving <= MAX_TURN and leaving <= MAX_TURN and dot(t_out, away) <= -leaving * norm(away)):
        return None
    if beyond:
        reach_in = _excursion_in(memory, trajectory, i)
        if reach_in is None:
            return None
        bound = max(reach_in, excursion(trajectory, memory.kind, after, rest))
    else:
        bound = line_bound(arriving, arriving, residual, magnitude)
    bound = min(bound, plain) + BOUND_FLOOR
    return Check(bound, bound <= tol, '' if bound <= tol else 'bound')
