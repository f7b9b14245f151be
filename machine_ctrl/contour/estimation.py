"""Real-time contour-error estimation for the tool tip and the tool orientation (Sencer,
Altintas & Croft 2009, seed 001_e18aed69c6dd27eb.txt, section 3, Eqs. 17-34), for any
machine of ours. No ROS: the offline experiment, the benchmark and contour_error_node call
the same objects.

Inputs per control step k:

* the reference tool trajectory, converted once from the axis reference q, q', q'' when it
  is streamed in (:func:`tool_reference`, :class:`ToolTrajectory`): tool tip P_ref,
  V = J_P q', A = J_P q'' + (dJ_P/dt) q', tool axis O_ref and its rate W = dO_ref/dt = J_O q'
  (Sencer's "angular velocity" omega = [dO_i, dO_j, dO_k], section 2 and Eq. 27), by
  central differences of the kinematics along the reference's Taylor polynomial;
* the measured axes q, through the machine's kinematics: actual P and O (one FK per step).

Tool tip (Sencer section 3.2), tracking error e = P_ref - P (Eq. 15):

* ``basic``: Frenet frame F = [t n b] at the reference point (Eqs. 17-18), e_F = F^T e
  (Eq. 19), contour error eps = e_n n + e_b b (Eq. 20);
* ``shifted``: the same with the frame taken at t - t_d, t_d = e_t / |V| (Eqs. 21-22);
* ``compensated``: the shifted frame plus the offset h = P_ref(t) - P_ref(t - t_d)
  (Eqs. 23-26): eps = n n^T (e - h) + b b^T (e - h) in the shifted frame, i.e. the distance
  of P from the path's tangent at the delayed point.

Tool orientation (section 3.3): eps_o = e_o - w (w . e_o), w = W/|W|, e_o = O_ref - O
(Eqs. 27-28), a 3-vector in the workpiece frame (rad for small errors). In drive
coordinates (Eq. 34) see :func:`rotary_contour_error`.

What we used where the seed's formulas have typos (README "Contour error ([5/7])"):

* Eq. (17) prints n = P''/|P''|, which is orthogonal to t only at constant feed; the
  "mutually orthogonal" normal of the text is the part of P'' normal to t, normalized
  (Frenet principal normal). eps of Eq. (20) depends only on t: eps = e - (e.t) t.
* Eq. (26) prints eps_F = F~^T eps + h~_F with eps (the unknown) on the right; it must be the
  tracking error e: eps_F = F~^T e + W F~^T h with W = diag(0, -1, -1, 1, 1) (Eq. 25).
* Eqs. (31)-(33) replace k^2 J_O^T J_O by the identity ("k^2 v^T J_O^T J_O v = v^T", Eq. 32,
  is a scalar identity, not a matrix one). That holds only when J_O^T J_O is a multiple of
  I; on the TRT machine J_O^T J_O = diag(1, cos^2 a). The exact drive-coordinate form of
  Eq. (28) is eps_R = e_R - v (v^T G e_R)/(v^T G v), G = J_O^T J_O; Eq. (34) is G = I.
* Eq. (36) maps the true orientation error to drive coordinates with J_O (3x2) applied to
  a 3-vector; it must be the pseudo-inverse J_O^+.

Degenerate reference (all without NaN): zero curvature (straight line, P'' parallel to P'
or zero) -> any unit normal (eps does not depend on it); a stop (P' = 0) -> the tangent
is P''s direction if the reference is accelerating, else the last direction of travel
(the estimator remembers it) or, before the first motion, the first one ahead, and t_d = 0;
an orientation at rest
(W = 0) -> the same rule with the tool axis's direction of motion. At a path's ends the
true error is the distance to the end segment (:class:`RestDirection`); a moving tool tip
already past the end (behind the start) gets the distance to the end point where that is
certainly the closest point (validity.beyond_end; on trt_5axis's final stop a line was
12.35 um off there).

Validity (:mod:`machine_ctrl.contour.validity`, README "Contour error", "Validity"): every
estimate carries a Check, a bound on |estimate - true contour error| from the path's geometry
around it, and valid = the bound within the tolerance. The estimates themselves are the
formulas above, unchanged; where their assumptions fail — a smooth path with the closest
point near the frame point: not at a join, a corner, a reversal, across the last rows of a
stop (where Eq. 21's t_d = e_t/|V| runs to its clamp and the frame lands on another segment:
the 483 um of the micromill's approach -> helix join), not beyond a path end where the end
point is not certainly closest — the bound says so and the step is invalid. The node
publishes invalid steps as NaN.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from machine_ctrl.contour.validity import (SPEED_TOL, Check, PathGeometry, PathMemory, Tolerance, angle,
                                           beyond_end, dot, line_check, nearer_row_angle, rest_check)
from machine_ctrl.model.kinematics import Kinematics, orientation_basis

ESTIMATORS = ('basic', 'shifted', 'compensated')
# assumed: below these the reference counts as at rest / as not curving; far below any
# motion a machine makes (SPEED_TOL = 1 nm/s, in validity.py; 1e-12 of the speed for the normal).
CURVATURE_TOL = 1e-12       # relative
# assumed: |t_d| is clamped to 50 ms, 6x the largest lag of the trt_5axis run (8 ms). Eq. (21)
# assumes the reference keeps its speed over t_d; in the last milliseconds of a stop the
# speed tends to 0 and e_t/|V| would shift the frame far back along the path (seen: 0.5 s,
# 2 mm on the micromill helix). The node keeps this much reference history, so it computes
# what the offline run computes.
MAX_SHIFT = 0.05            # s
# assumed: an estimate's bound looks at the reference rows within 0.2 s of its step, both ways
# (4 MAX_SHIFT: a window of a few um of arc around the closest point spans more steps than the
# shift where the path starts slowly; validity.py). The node keeps as many rows behind the
# newest step, and the trajectory source streams further ahead (3000 rows by default).
HORIZON = 0.2               # s
# assumed: 20 us balances truncation (h^2/6 |d3P/dt3| ~ 1e-11 m/s in V) against rounding
# (eps |P| / h^2 ~ 3e-8 m/s^2 in A, which only enters through the tangent at a start).
DIFFERENCE_STEP = 2e-5      # s


def tool_reference(kinematics: Kinematics, q, qd, qdd):
    """Reference tool trajectory of axis rows q, q', q'' (m x n): P, V, A, O, W (m x 3 each,
    workpiece frame), V = J_P q', A = J_P q'' + (dJ_P/dt) q' (Sencer Eq. 11), W = J_O q'.

    By central differences of the forward kinematics along the reference's own Taylor
    polynomial q(+-h) = q +- h q' + h^2/2 q'' (h = DIFFERENCE_STEP): (P+ - P-)/2h = J q'
    and (P+ - 2P + P-)/h^2 = J q'' + (dJ/dt) q', both to O(h^2); three FK calls per row
    cost half of a Jacobian plus its finite difference; all rows' at once
    (Kinematics.forward_many: a chunk of 500 rows in ~0.6 ms, not ~7 ms row by row)."""
    q, qd, qdd = (np.asarray(x, float).reshape(-1, kinematics.n) for x in (q, qd, qdd))
    h = DIFFERENCE_STEP
    m = len(q)
    positions, axes = kinematics.forward_many(np.concatenate((q, q + h * qd + 0.5 * h * h * qdd,
                                                              q - h * qd + 0.5 * h * h * qdd)))
    (p, p_ahead, p_back), (o, o_ahead, o_back) = positions.reshape(3, m, 3), axes.reshape(3, m, 3)
    return (p, (p_ahead - p_back) / (2 * h), (p_ahead - 2 * p + p_back) / (h * h), o, (o_ahead - o_back) / (2 * h))


class ToolTrajectory:
    """Reference tool rows by control step, filled chunk by chunk (like ReferenceBuffer: a
    chunk replaces everything from its first step on), with cubic Hermite interpolation
    between steps for the shifted estimators and the true-error search, and the geometry of
    the tool-tip and tool-axis paths (arc length, turning: :class:`validity.PathGeometry`)
    that bounds the estimates. `horizon`: the steps each way an estimate's bound may look at
    (HORIZON; the node keeps that many behind the newest step)."""

    def __init__(self, period: float):
        self.period = period
        self.horizon = int(math.ceil(HORIZON / period))
        self.first = 0
        self.rows = np.empty((5, 0, 3))          # P, V, A, O, W
        self.geometry = (PathGeometry(), PathGeometry())     # tool tip (P, V), tool axis (O, W)
        self.version = 0                         # counts changes of rows already held

    @classmethod
    def from_reference(cls, kinematics: Kinematics, reference) -> ToolTrajectory:
        trajectory = cls(reference.period)
        trajectory.add(0, *tool_reference(kinematics, reference.position, reference.velocity,
                                          reference.acceleration))
        return trajectory

    @property
    def end(self) -> int:
        """First step not held."""
        return self.first + self.rows.shape[1]

    def __len__(self) -> int:
        return self.rows.shape[1]

    def has(self, step: int) -> bool:
        return self.first <= step < self.end

    def add(self, first_step: int, p, v, a, o, w) -> None:
        chunk = np.array([p, v, a, o, w], float)
        if first_step != self.end:
            self.version += 1
        if not len(self) or first_step > self.end or first_step < self.first:
            self.first, self.rows = first_step, chunk
        else:
            self.rows = np.concatenate((self.rows[:, :first_step - self.first], chunk), axis=1)
        index = first_step - self.first
        for geometry, (position, rate) in zip(self.geometry, ((0, 1), (3, 4))):
            geometry.replace_from(index, chunk[position], chunk[rate],
                                  self.rows[position, index - 1] if index else None)

    def drop_before(self, step: int) -> None:
        cut = min(step, self.end) - self.first
        if cut > 0:                     # nothing to drop (empty, or the step not past the first row): untouched
            self.rows, self.first = self.rows[:, cut:], self.first + cut
            for geometry in self.geometry:
                geometry.drop(cut)

    def row(self, step: int) -> list[list[float]]:
        """[P, V, A, O, W] of a step held here, as lists of floats (per-step code runs on
        floats: several times faster than numpy on 3-vectors)."""
        return self.rows[:, step - self.first].tolist()

    def sample(self, step: float) -> list[list[float]]:
        """[P, V, A] at a fractional step, clamped into the held rows: P and V by cubic
        Hermite from (P, V) and (V, A), A linearly."""
        s = min(max(step - self.first, 0.0), len(self) - 1.0)
        i = min(int(s), len(self) - 2) if len(self) > 1 else 0
        u = s - i
        if u == 0.0:
            return self.rows[:3, i].tolist()
        (p0, v0, a0), (p1, v1, a1) = self.rows[:3, i].tolist(), self.rows[:3, i + 1].tolist()
        h = self.period
        return [[hermite(x0, d0, x1, d1, u, h) for x0, d0, x1, d1 in zip(p0, v0, p1, v1)],
                [hermite(x0, d0, x1, d1, u, h) for x0, d0, x1, d1 in zip(v0, a0, v1, a1)],
                [x0 + u * (x1 - x0) for x0, x1 in zip(a0, a1)]]

    def next_moving(self, step: int, field: int, tolerance: float) -> int | None:
        """First held step >= `step` whose rate row `field` (1: V, 4: W) has a norm above
        `tolerance`, or None."""
        rates = self.rows[field, max(step - self.first, 0):]
        moving = np.flatnonzero((rates * rates).sum(axis=1) > tolerance * tolerance)
        return None if not len(moving) else self.first + max(step - self.first, 0) + int(moving[0])


def hermite(x0, d0, x1, d1, u, h):
    """Cubic Hermite between x0 (slope d0) and x1 (slope d1) over an interval h, at u in [0, 1]
    (floats, or arrays broadcasting against each other)."""
    u2 = u * u
    u3 = u2 * u
    return ((2 * u3 - 3 * u2 + 1) * x0 + (u3 - 2 * u2 + u) * h * d0
            + (-2 * u3 + 3 * u2) * x1 + (u3 - u2) * h * d1)


def unit(x, tol: float):
    """(x/|x|, |x|), or (None, |x|) if |x| <= tol."""
    norm = math.sqrt(dot(x, x))
    return ([x[0] / norm, x[1] / norm, x[2] / norm], norm) if norm > tol else (None, norm)


def reject(e, d) -> list[float]:
    """e without its component along the unit vector d: e - d (d . e)."""
    k = dot(d, e)
    return [e[0] - k * d[0], e[1] - k * d[1], e[2] - k * d[2]]


def frenet_frame(velocity, acceleration):
    """[t, n, b] of the reference at one step (Sencer Eqs. 17-18, with n the part of P''
    normal to t, see the module docstring), or None when it is at rest (P' = P'' = 0)."""
    t, speed = unit(velocity, SPEED_TOL)
    if t is None:
        t = unit(acceleration, SPEED_TOL)[0]      # starting or stopping: P'' is along the path
        if t is None:
            return None
    n = unit(reject(acceleration, t), CURVATURE_TOL * max(speed * speed, 1.0))[0]
    if n is None:                                 # straight: any normal (eps does not depend on it)
        n = orientation_basis(np.array(t))[:, 0].tolist()
    b = [t[1] * n[2] - t[2] * n[1], t[2] * n[0] - t[0] * n[2], t[0] * n[1] - t[1] * n[0]]
    return t, n, b


def components(frame, e) -> list[float]:
    """F^T e (Eq. 19) for F = [t, n, b]."""
    return [dot(frame[0], e), dot(frame[1], e), dot(frame[2], e)]


def normal_part(frame, e_frenet) -> list[float]:
    """e_n n + e_b b (Eq. 20)."""
    _, n, b = frame
    return [e_frenet[1] * n[i] + e_frenet[2] * b[i] for i in range(3)]


class RestDirection:
    """Direction of travel of one reference quantity (rate rows `field` of the trajectory)
    for steps where it is at rest: the last direction it moved in (a stop: the reference
    point is the end of the path so far), or before it has moved, the first direction
    ahead (the start of the path). At a path end the contour error is the distance to the
    end *segment*: only the component along the path is dropped when the actual point is
    on the path's side of the end, all of the error counts when it is beyond the end."""

    def __init__(self, field: int):
        self.field = field
        self.last = None
        self._ahead: tuple[int, list[float]] | None = None
        self._at_rest_until: tuple[int, int] | None = None    # (trajectory version, end step)

    def moved(self, direction) -> None:
        self.last = direction

    def contour_error(self, trajectory: ToolTrajectory, step: int, e) -> list[float]:
        return self.resolve(trajectory, step, e)[0]

    def resolve(self, trajectory: ToolTrajectory, step: int, e):
        """(contour error, direction used or None, beyond the end / behind the start, step of
        the first motion ahead when that gave the direction, else None)."""
        if self.last is not None:
            direction, beyond, ahead = self.last, dot(e, self.last) < 0.0, None      # ahead of the stop
        else:
            direction = self._first_ahead(trajectory, step)
            if direction is None:
                return list(e), None, False, None
            beyond, ahead = dot(e, direction) > 0.0, self._ahead[0]                # behind the start
        return (list(e) if beyond else reject(e, direction)), direction, beyond, ahead

    def _first_ahead(self, trajectory: ToolTrajectory, step: int):
        if self._ahead is None or self._ahead[0] < step:
            start = step          # rows found at rest before, unchanged since, are not scanned again
            if self._at_rest_until is not None and self._at_rest_until[0] == trajectory.version:
                start = max(step, self._at_rest_until[1])
            found = trajectory.next_moving(start, self.field, SPEED_TOL) if start < trajectory.end else None
            if found is None:
                self._at_rest_until = (trajectory.version, trajectory.end)
                return None
            self._ahead = (found, unit(trajectory.rows[self.field, found - trajectory.first].tolist(),
                                       SPEED_TOL)[0])
        return self._ahead[1]


@dataclass(frozen=True)
class TipEstimate:
    vector: list[float]     # contour error eps (m, workpiece frame), from P towards the path
    frenet: list[float]     # [e_t, e_n, e_b] in the frame used (Eq. 19; Eq. 26 for compensated); for a tool
                            # past the path's end, the frame's, though `vector` is then the end point's
    delay: float            # t_d (s), Eq. (21); 0 for basic and at rest
    check: Check            # |vector - true eps| <= check.bound; valid or not (module validity)

    @property
    def valid(self) -> bool:
        return self.check.valid


class ToolTipEstimator:
    """One of the Frenet-frame estimators of Sencer section 3.2, stepped once per control step
    in step order (it remembers the direction of travel for stops, and the path that led to
    a rest, for the bound)."""

    def __init__(self, method: str = 'compensated', tolerance: Tolerance = Tolerance()):
        if method not in ESTIMATORS:
            raise ValueError(f'estimator must be one of {", ".join(ESTIMATORS)}, got {method!r}')
        self.method = method
        self.tolerance = tolerance
        self.rest = RestDirection(1)
        self.memory = PathMemory(0)

    def estimate(self, trajectory: ToolTrajectory, step: int, p, row=None) -> TipEstimate:
        p_ref, v_ref, a_ref = (row or trajectory.row(step))[:3]
        e = [p_ref[0] - p[0], p_ref[1] - p[1], p_ref[2] - p[2]]            # Eq. (15)
        self.memory.note(trajectory, step)
        frame = frenet_frame(v_ref, a_ref)
        if frame is None:
            vector, direction, beyond, ahead = self.rest.resolve(trajectory, step, e)
            return TipEstimate(vector, [0.0, 0.0, 0.0], 0.0, rest_check(
                self.memory, self.tolerance, trajectory, step, vector, e, direction, beyond, ahead, p))
        self.rest.moved(frame[0])
        e_frenet = components(frame, e)                                     # Eq. (19)
        geometry = trajectory.geometry[0]
        i = step - trajectory.first
        s_k = float(geometry.s[i])
        turn_k = 0.0 if geometry.moving[i] else angle(frame[0], geometry.last[i].tolist())   # T from A at a stop
        if self.method == 'basic':
            vector = normal_part(frame, e_frenet)                           # Eq. (20)
            return self._past_an_end(TipEstimate(vector, e_frenet, 0.0, line_check(
                self.memory, self.tolerance, trajectory, step, vector, e, e_frenet[0], s_k, s_k, turn_k, p)),
                trajectory, step, p, e)
        speed = math.sqrt(dot(v_ref, v_ref))
        delay = e_frenet[0] / speed if speed > SPEED_TOL else 0.0           # Eq. (21)
        delay = min(max(delay, -MAX_SHIFT), MAX_SHIFT)
        at = step - delay / trajectory.period
        p_d, v_d, a_d = trajectory.sample(at)
        shifted = frenet_frame(v_d, a_d)                                    # Eq. (22)
        at = min(max(at - trajectory.first, 0.0), len(trajectory) - 1.0)   # where sample() took it
        s_d = geometry.arc(at)
        if shifted is None:
            shifted, s_t, turn_t = frame, s_k, turn_k
        else:                             # T interpolated: its angle to a row's direction in the window
            s_t, turn_t = s_d, nearer_row_angle(geometry, shifted[0], at)
        e_shifted = components(shifted, e)
        if self.method == 'compensated':                                    # Eqs. (23)-(26)
            h_frenet = components(shifted, [p_ref[i] - p_d[i] for i in range(3)])
            e_shifted = [e_shifted[0], e_shifted[1] - h_frenet[1], e_shifted[2] - h_frenet[2]]
            residual, s_c = e_shifted[0] - h_frenet[0], s_d
        else:
            residual, s_c = e_shifted[0], s_k
        vector = normal_part(shifted, e_shifted)
        return self._past_an_end(TipEstimate(vector, e_shifted, delay, line_check(
            self.memory, self.tolerance, trajectory, step, vector, e, residual, s_c, s_t, turn_t, p)), trajectory, step,
            p, e)

    def _past_an_end(self, estimate: TipEstimate, trajectory: ToolTrajectory, step: int, p, e) -> TipEstimate:
        """A tool beyond the path's end (behind its start), which no frame's line gives: the
        distance to that end point instead, where it is certainly the closest point
        (validity.beyond_end); else the estimate as it was, marked invalid."""
        if estimate.check.reason not in ('end', 'start'):
            return estimate
        found = beyond_end(self.memory, self.tolerance, trajectory, step, p, e, estimate.check.reason)
        return estimate if found is None else TipEstimate(found[0], estimate.frenet, estimate.delay, found[1])


def orientation_contour_error(o_ref, w_ref, o) -> list[float] | None:
    """Sencer Eqs. (27)-(28): the orientation tracking error e_o = O_ref - O without its
    component along the tool axis's motion w = W/|W|; None when the axis is at rest."""
    w = unit(w_ref, SPEED_TOL)[0]
    return None if w is None else reject([o_ref[0] - o[0], o_ref[1] - o[1], o_ref[2] - o[2]], w)


def rotary_contour_error(e_r, v_r, j_o) -> np.ndarray:
    """Eq. (28) in drive coordinates of the rotary axes R, exactly: eps_R = e_R -
    v (v^T G e_R)/(v^T G v), G = J_O^T J_O (J_O: 3 x r, the tool-axis columns of R). The
    printed Eq. (34) is this with G = I (:func:`rotary_contour_error_eq34`)."""
    g = j_o.T @ j_o
    v = np.asarray(v_r, float)
    denominator = v @ g @ v
    return e_r - v * (v @ g @ e_r) / denominator if denominator > SPEED_TOL ** 2 else np.asarray(e_r, float)


def rotary_contour_error_eq34(e_r, v_r) -> np.ndarray:
    """Eq. (34) as printed: eps_R = e_R - v (v . e_R), v = v_R/|v_R| (see the module docstring)."""
    v = np.asarray(v_r, float)
    norm = float(np.linalg.norm(v))
    return np.asarray(e_r, float) if norm <= SPEED_TOL else e_r - v * (v @ e_r) / (norm * norm)


def drive_coordinates(j_o, eps_o) -> np.ndarray:
    """An orientation error vector in drive coordinates of the rotary axes: J_O^+ eps_o
    (Eq. 36 with the pseudo-inverse, see the module docstring)."""
    return np.linalg.lstsq(j_o, eps_o, rcond=None)[0]


class OrientationEstimator:
    """Eq. (28) per control step, in step order (it remembers the tool axis's direction of
    motion for rests, :class:`RestDirection`, and the path that led to a rest)."""

    def __init__(self, tolerance: Tolerance = Tolerance()):
        self.tolerance = tolerance
        self.rest = RestDirection(4)
        self.memory = PathMemory(1)

    def estimate(self, trajectory: ToolTrajectory, step: int, o, row=None) -> list[float]:
        return self.update(trajectory, step, o, row).vector

    def update(self, trajectory: ToolTrajectory, step: int, o, row=None) -> OrientationEstimate:
        """The estimate with its bound (module validity)."""
        o_ref, w_ref = (row or trajectory.row(step))[3:]
        e = [o_ref[i] - o[i] for i in range(3)]
        self.memory.note(trajectory, step)
        w = unit(w_ref, SPEED_TOL)[0]
        if w is None:
            vector, direction, beyond, ahead = self.rest.resolve(trajectory, step, e)
            return OrientationEstimate(vector, rest_check(
                self.memory, self.tolerance, trajectory, step, vector, e, direction, beyond, ahead, o))
        self.rest.moved(w)
        vector = reject(e, w)                                              # Eq. (28)
        s_k = float(trajectory.geometry[1].s[step - trajectory.first])
        return OrientationEstimate(vector, line_check(
            self.memory, self.tolerance, trajectory, step, vector, e, dot(w, e), s_k, s_k, 0.0, o))


@dataclass(frozen=True)
class OrientationEstimate:
    vector: list[float]     # eps_o, workpiece frame (Eq. 28)
    check: Check            # |vector - true eps_o| <= check.bound (rad); valid or not

    @property
    def valid(self) -> bool:
        return self.check.valid


@dataclass(frozen=True)
class ContourEstimate:
    tool_tip: TipEstimate
    orientation: OrientationEstimate


class ContourEstimator:
    """Per control step, in step order: measured axes -> FK -> tool-tip and orientation
    contour errors, each with its bound and validity."""

    def __init__(self, kinematics: Kinematics, method: str = 'compensated',
                 tolerances: tuple[Tolerance, Tolerance] = (Tolerance(), Tolerance())):
        self.kinematics = kinematics
        self.tip = ToolTipEstimator(method, tolerances[0])
        self.orientation = OrientationEstimator(tolerances[1])

    def update(self, trajectory: ToolTrajectory, step: int, q) -> ContourEstimate:
        p, o = self.kinematics.forward(q)
        row = trajectory.row(step)
        return ContourEstimate(self.tip.estimate(trajectory, step, p.tolist(), row),
                               self.orientation.update(trajectory, step, o.tolist(), row))
