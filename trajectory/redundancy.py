"""Redundancy resolution of a redundant machine along a toolpath (Yuen thesis §3.3-3.8,
Algorithm 1): axis positions q[n] and their geometric derivatives dq/ds, d²q/ds², d³q/ds³
at fixed displacement steps s[n] = n Δs.

The toolpath R(s) = [P(s); O(s)] (Eq. 3.12) is any object with ``length`` (m) and
``tangents(s) -> [(P, O), (dP/ds, dO/ds)]`` that takes an array s (M,) and returns (M, 3)
arrays (as spline.ArcLengthPath); when it also has
``knot_s``, the arc lengths of its CL points, a failure names the points where.

Resolved rate (Eq. 3.27, with the errata of seed-notes.md applied)::

    dq/ds = g(s, q) = J_t^# (dR_t/ds + K_e e_t) - beta (I - J_t^# J_t) grad H(q)

* J_t is the 5 x n task Jacobian [dP/dq; B^T dO/dq] (B = orthonormal basis of the plane
  normal to the current tool axis O(q), as :func:`machine_ctrl.model.kinematics.task_jacobian`):
  the 6 x n J of Eq. 3.13 has rank <= 5, so J J^T of Eq. 3.15 is never invertible. The task
  rate is dR_t/ds = [dP/ds; B^T dO/ds] and the task error (Eq. 3.26) is
  e_t = [P(s) - P(q); B^T (O(s) - O(q))].
* J_t^# is the singularity-robust inverse of Eq. 3.21, J_t^T (J_t J_t^T + mu I)^-1, computed
  from the SVD of J_t as sum_i v_i sigma_i / (sigma_i^2 + mu) u_i^T over the r task
  directions the active axes can move (r = 5 for the whole machine; fewer when axes are
  frozen, e.g. r = 2 for the x-y-only circle of §3.4). The damping mu follows Eq. 3.22 with
  the manipulability w = prod of those r singular values (= sqrt(det(J_t J_t^T)) for r = 5).
* The projector is I - J^# J (the printed I - J J^# of Eq. 3.18 is an erratum) and the
  gradient is *descended*: -beta grad H with beta > 0 (the printed +beta climbs H).
* Stroke cost: H(q) = sum_i u_i^2 / (1 - u_i^2), u_i = (q_i - c_i) / h_i, over the active
  axes with a stroke (c_i centre, h_i half-stroke; the unlimited c_f is left out). For a
  symmetric stroke this is sum q^2 / (q_max^2 - q^2), the function whose exact gradient is
  the printed Eq. 3.20 (Eq. 3.19 as printed is a different function, seed-notes.md); it is
  dimensionless, i.e. already normalized by the strokes, so micro- and macro-axes are
  penalized alike at the same fraction of their stroke. Exact gradient:
  dH/dq_i = 2 u_i / (h_i (1 - u_i^2)^2).

Integration: classical 4th-order Runge-Kutta over s (Eq. 3.24 / Algorithm 1), Δs = S/N.
After every step an optional Newton projection q += J_t^# e_t (at most
``projection_iterations``) keeps the task error below ``projection_tolerance``.

Derivatives: along the exact solution e_t = 0 identically, so every derivative of the drift
term vanishes there and q' = g0(s, q), q'' = d/ds g0, q''' = d²/ds² g0 with g0 the rate
without the K_e term. q'[n] = g0(s[n], q[n]) is computed exactly at every node (it is the
first RK4 stage of step n without its drift part: no extra evaluation); q'' and q''' are the
first and second derivatives of the samples q'[n] along s, by 7-point finite-difference
stencils on the uniform grid (weights from the Taylor conditions; centred, and shifted
one-sided within three steps of the path ends). Truncation: O(Δs^6) centred, i.e.
~(Δs/ρ)^6 relative for a path feature of length ρ (the 4 mm circle at Δs = 20 µm: ~1e-14),
O(Δs^5) / O(Δs^4) one-sided; the stiff nullspace start-up transient (length ~0.2 mm, 10
steps) is the worst feature. Round-off: ~eps |q'| sum|w| / Δs² for q''' (~1e-4 1/m² at
20 µm, against |q'''| ~ 1/ρ² ~ 1e4-1e5 1/m² on mm-sized features). Earlier versions
differenced g0 along a Taylor curve 1 µm off the grid: five more rate evaluations per node.
Caveat: mu of Eq. 3.22 is only C¹ at w = w0, so q''' jumps where w crosses w0.

Cost: per step four rate evaluations (the RK4 stages) and the projection's task evaluation,
whose FK and Jacobian are reused by the next step's first stage; R(s) and dR/ds are
evaluated once, vectorized, at the nodes and the RK4 midpoints. The loop runs compiled
(trajectory/resolved_rate.py, ~4x faster) on a machine whose kinematic chains pack, which
all of ours do; interpreted here, on Pinocchio, otherwise.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from machine_ctrl.model.config import MachineConfig
from machine_ctrl.model.kinematics import Kinematics
from trajectory.axis_limits import amount, outside_stroke, stroke_text


class ResolutionFailed(ValueError):
    """:func:`resolve` could not follow the path. `kind` is 'unreachable' (R(0) cannot be
    reached: :func:`initial_configuration`), 'out_of_stroke' (the axes left their strokes
    before the integration broke down) or 'singular' (the task Jacobian lost rank inside the
    strokes); `s` the arc length (m) where; `reason` a sentence naming the problem and where
    (also the exception text)."""

    def __init__(self, kind: str, reason: str, s: float):
        super().__init__(reason)
        self.kind, self.reason, self.s = kind, reason, s


def stroke_problems(machine: MachineConfig, q) -> list[str]:
    """'<axis> at <value> <unit>, outside its stroke [lo, hi] <unit> by <excess>' for each
    axis of q (one configuration) outside its stroke; [] when every one is inside."""
    return [problem for problem in (outside_stroke(axis, value) for axis, value in zip(machine.axes, q)) if problem]


def start_out_of_stroke(machine: MachineConfig, q0) -> str | None:
    """Why a path cannot be followed from the start configuration q0, or None when q0 is
    inside every stroke."""
    problems = stroke_problems(machine, q0)
    return 'the start configuration is outside the strokes: ' + '; '.join(problems) if problems else None


def point_before(knot_s, s: float) -> int:
    """The CL point i whose span [knot_s[i], knot_s[i + 1]] holds the arc length s (m), for
    the arc lengths knot_s of the CL points (the last span holds the end)."""
    return min(int(np.searchsorted(knot_s, s, side='right')) - 1, len(knot_s) - 2)


def where_on(path, s: float) -> str:
    """'between points 38 and 39 (s = 49.52 mm)' (or 'at point 38 (...)'): where the arc
    length s (m) lies among the CL points of `path` when it has their arc lengths
    (`knot_s`, as spline.ArcLengthPath), else 'at s = 49.52 mm'."""
    knots = getattr(path, 'knot_s', None)
    if knots is None:
        return f'at s = {s * 1e3:.6g} mm'
    i = point_before(knots, s)
    at = f'at point {i}' if s == knots[i] else f'between points {i} and {i + 1}'
    return f'{at} (s = {s * 1e3:.6g} mm)'


def _failure(machine: MachineConfig, s, qs, path=None) -> ResolutionFailed:
    """Why the integration broke down (a numpy LinAlgError or a non-finite rate) after the
    configurations qs (K, n) at the arc lengths s[:K] of `path` (named by where_on). When
    the axes must go to a stroke end, the stroke cost holds them inside until one is there
    and the stiff barrier throws the integration out of the strokes: out_of_stroke, named
    by the axes at (>= 99 % of the way to) a stroke end in the last configuration inside,
    with their distance to it (or, if the first is outside already, its axes outside).
    Singular if none left."""
    limited = [i for i, a in enumerate(machine.axes) if a.stroke is not None]
    lo = np.array([machine.axes[i].stroke[0] for i in limited])
    hi = np.array([machine.axes[i].stroke[1] for i in limited])
    q = qs[:, limited]
    outside = np.flatnonzero(np.any((q < lo) | (q > hi) | ~np.isfinite(q), axis=1))
    if not len(outside):
        j = len(qs) - 1
        return ResolutionFailed('singular', f'the kinematics are singular {where_on(path, s[j])} (the task '
                                'Jacobian loses rank; the redundancy resolution cannot follow the path there)',
                                float(s[j]))
    j = int(outside[0])
    if j == 0:
        return ResolutionFailed('out_of_stroke', start_out_of_stroke(machine, qs[0]), 0.0)
    last = q[j - 1]
    share = np.abs(last - 0.5 * (lo + hi)) / (0.5 * (hi - lo))      # 1 at a stroke end
    ends = np.flatnonzero(share >= 0.99) if np.any(share >= 0.99) else [int(np.argmax(share))]
    named = []
    for k in ends:
        axis, value = machine.axes[limited[k]], last[k]
        margin = min(value - axis.stroke[0], axis.stroke[1] - value)
        named.append(f'{axis.name} at {value:.6g} {axis.unit}, {amount(margin, axis.unit)} from the end of its '
                     f'stroke {stroke_text(axis)}')
    return ResolutionFailed('out_of_stroke', f'the redundancy resolution cannot keep the axes inside their strokes '
                            f'{where_on(path, s[j - 1])}: {"; ".join(named)}', float(s[j - 1]))


@dataclass(frozen=True)
class RedundancySettings:
    """Tuning of the resolution. Lengths in m, angles in rad."""
    # assumed: not stated in the thesis (seed-notes.md). 20 µm keeps the stiffest nullspace
    # mode (rate at least 2 beta/h_f² = 1e4 1/m for the 100 µm fine strokes; Δs rate 0.2 at
    # the centre, ~1 where the axis settles) within a third of RK4's real-axis stability
    # limit 2.79, and gives 1257 points per turn of the 4 mm circle.
    step: float = 20e-6
    # assumed: beta (m², because grad H is in 1/m). On a unit-speed path the fine axis settles
    # where its gradient 2u/(h(1-u²)²) ~ 1/beta, i.e. |u| ~ 0.5 (52 µm of the 100 µm fine
    # stroke) for beta = 5e-5; the nullspace time constant is h_f²/beta = 0.2 mm of path.
    beta: float = 5e-5
    # assumed: K_e (1/m). Task errors decay as exp(-K_e s): 1/e over 1 mm of path, and
    # K_e Δs = 0.02 is far inside the stability limit of the integration.
    drift_gain: float = 1000.0
    # assumed: w0, mu0 of Eq. 3.22. At the micromill's home w = 2.8 (singular values
    # 1.41 x3, 1.0 x2); 1e-3 is far from any configuration inside the strokes. mu0 = 1e-6 is
    # the thesis's Fig. 3.6 value (tight accuracy).
    manipulability_threshold: float = 1e-3
    damping_max: float = 1e-6
    # Axis names that move; the others keep q0 (None: the machine's planned_axes, all but the
    # fine axes of a Cartesian coupling).
    active_axes: tuple[str, ...] | None = None
    # Newton projection after each RK4 step (0 iterations: off).
    projection_iterations: int = 2
    projection_tolerance: float = 1e-13
    # assumed: scale (rad) of an unlimited axis in the stroke-weighted Newton solve for q0;
    # about 1/6 of a turn, so c_f is used only as much as the coarse axes.
    unlimited_scale: float = 1.0
    initial_iterations: int = 50

    def __post_init__(self):
        for name in ('step', 'drift_gain', 'manipulability_threshold', 'unlimited_scale'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f'{name} must be a positive finite number, got {value!r}')
        for name in ('beta', 'damping_max', 'projection_tolerance'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f'{name} must be a non-negative finite number, got {value!r}')


@dataclass
class Resolution:
    """Result of :func:`resolve`: s (N+1,), q, dq/ds, d²q/ds², d³q/ds³ (N+1, n) in SI units
    (m, rad per m^k of path), and the largest task errors of FK(q[n]) against R(s[n]):
    position (m, Euclidean) and orientation (rad, angle between the tool axes)."""
    s: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    dddq: np.ndarray
    max_position_error: float
    max_orientation_error: float
    axis_names: tuple[str, ...] = ()


def _basis(o: np.ndarray) -> np.ndarray:
    """Same basis as machine_ctrl.model.kinematics.orientation_basis (written out: np.cross on
    3-vectors costs more than the rest of the rate evaluation)."""
    ox, oy, oz = o.tolist()
    if abs(ox) < 0.9:       # helper e_x: e1 = o x e_x
        a, b, c = 0.0, oz, -oy
    else:                   # helper e_y: e1 = o x e_y
        a, b, c = -oz, 0.0, ox
    norm = math.sqrt(np.array((a, b, c)) @ np.array((a, b, c)))     # numpy's dot, as before
    a, b, c = a / norm, b / norm, c / norm
    return np.array(((a, oy * c - oz * b), (b, oz * a - ox * c), (c, ox * b - oy * a)))


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    c = np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])
    return math.atan2(math.sqrt(c @ c), float(a @ b))


class _Resolver:
    def __init__(self, kinematics: Kinematics, machine: MachineConfig,
                 settings: RedundancySettings):
        self.kin, self.settings = kinematics, settings
        names = tuple(machine.axis_names)
        active = machine.planned_axes if settings.active_axes is None else tuple(settings.active_axes)
        unknown = [a for a in active if a not in names]
        if unknown or not active:
            raise ValueError(f'active_axes: unknown axis names {unknown}' if unknown
                             else 'active_axes is empty')
        self.active = np.array([names.index(a) for a in names if a in active])
        self.every_axis = len(self.active) == len(names)
        centre, half, scale, limited = [], [], [], []
        for k, i in enumerate(self.active):
            stroke = machine.axes[i].stroke
            if stroke is None:
                scale.append(settings.unlimited_scale)
            else:
                limited.append(k)
                centre.append(0.5 * (stroke[0] + stroke[1]))
                half.append(0.5 * (stroke[1] - stroke[0]))
                scale.append(half[-1])
        self.limited = np.array(limited, int)
        self.limited_axes = self.active[self.limited]   # the same axes, indexed in the full q
        self.centre, self.half = np.array(centre), np.array(half)
        self.scale = np.array(scale)
        self.rank = 5

    # --- pieces of Eq. 3.27 -------------------------------------------------------------
    def task(self, q):
        """P, O, B and the task Jacobian J_t restricted to the active axes."""
        p, o, jac = self.kin.forward_and_jacobian(q)
        b = _basis(o)
        if not self.every_axis:
            jac = jac[:, self.active]
        jt = np.empty((5, jac.shape[1]))
        jt[:3] = jac[:3]
        np.dot(b.T, jac[3:], out=jt[3:])
        return p, o, b, jt

    def damped_inverse(self, jt):
        """J_t^# of Eq. 3.21 with mu of Eq. 3.22 over the r reachable task directions. For
        r = 5 (every task direction) this is J_t^T (J_t J_t^T + mu I)^-1 with
        w = sqrt(det(J_t J_t^T)) as printed (a 5 x 5 inverse: cheaper than the SVD)."""
        if self.rank == 5:
            a = jt @ jt.T
            w = math.sqrt(max(np.linalg.det(a), 0.0))
            w0 = self.settings.manipulability_threshold
            if w < w0:
                a[np.diag_indices(5)] += self.settings.damping_max * (1.0 - w / w0) ** 2
            return jt.T @ np.linalg.inv(a)
        u, sig, vt = np.linalg.svd(jt, full_matrices=False)
        r = self.rank
        sig = sig[:r]
        w = float(np.prod(sig))
        w0 = self.settings.manipulability_threshold
        mu = self.settings.damping_max * (1.0 - w / w0) ** 2 if w < w0 else 0.0
        return (vt[:r].T * (sig / (sig * sig + mu))) @ u[:, :r].T

    def grad_h(self, q):
        """Exact gradient of H = sum u²/(1-u²) (the cost whose gradient Eq. 3.20 prints) over
        the active axes, at the full axis positions q."""
        g = np.zeros(len(self.active))
        if len(self.limited):
            u = (q[self.limited_axes] - self.centre) / self.half
            # a stage outside the stroke would flip the barrier's sign: clip just inside
            u = np.minimum(np.maximum(u, -1.0 + 1e-9), 1.0 - 1e-9)
            g[self.limited] = 2.0 * u / (self.half * (1.0 - u * u) ** 2)
        return g

    def rate(self, target, q, task=None):
        """(g, g0) at one s: g(s, q) of Eq. 3.27 and g0, the same without the drift term, as
        full n-vectors (frozen axes 0). `target` = (P, O, dP/ds, dO/ds) of R at s; `task`, if
        given, is self.task(q) already evaluated."""
        p, o, b, jt = self.task(q) if task is None else task
        pd, od, dpd, dod = target
        jsharp = self.damped_inverse(jt)
        dqa = jsharp @ np.concatenate((dpd, b.T @ dod))
        beta = self.settings.beta
        if beta:
            grad = self.grad_h(q)
            dqa -= beta * (grad - jsharp @ (jt @ grad))
        if self.every_axis:
            g0 = dqa
        else:
            g0 = np.zeros_like(q)
            g0[self.active] = dqa
        g = g0
        if self.settings.drift_gain:
            error = np.concatenate((pd - p, b.T @ (od - o)))
            drift = jsharp @ (self.settings.drift_gain * error)
            if self.every_axis:
                g = g0 + drift
            else:
                g = g0.copy()
                g[self.active] += drift
        return g, g0

    # --- Newton solves ----------------------------------------------------------------
    def project(self, pd, od, q, iterations, tolerance, weighted=False):
        """Newton iterations q += J^# e_t on the active axes towards R = (pd, od); returns q,
        position error (m), orientation error (rad) and self.task(q), all of the last
        evaluation."""
        q = q.copy()
        for it in range(iterations + 1):
            task = self.task(q)
            p, o, b, jt = task
            e = np.concatenate((pd - p, b.T @ (od - o)))
            d = pd - p
            ep, eo = math.sqrt(d.dot(d)), _angle(o, od)     # np.linalg.norm's own formula
            if (ep <= tolerance and eo <= tolerance) or it == iterations:
                break
            if weighted:    # stroke-weighted least norm: each axis in proportion to its stroke
                jw = jt * self.scale
                u, sig, vt = np.linalg.svd(jw, full_matrices=False)
                keep = sig > 1e-9 * sig[0]
                step = self.scale * ((vt[keep].T / sig[keep]) @ (u[:, keep].T @ e))
            else:
                step = self.damped_inverse(jt) @ e
            q[self.active] += step
        return q, ep, eo, task


def _fd_weights(offsets, order: int) -> np.ndarray:
    """Weights w with sum_i w_i f(x + offsets_i h) = h^order f^(order)(x) + O(h^len(offsets)
    - order): the Taylor (Vandermonde) conditions solved exactly."""
    offsets = np.asarray(offsets, float)
    vander = offsets[None, :] ** np.arange(len(offsets))[:, None]
    rhs = np.zeros(len(offsets))
    rhs[order] = math.factorial(order)
    return np.linalg.solve(vander, rhs)


# assumed: 7-point stencils for q'', q''' from q' (module docstring): O(Δs^6) centred,
# O(Δs^5)/O(Δs^4) within three steps of the path ends, where they are one-sided.
_STENCIL = 7


def _along_s(f: np.ndarray, h: float, order: int) -> np.ndarray:
    """d^order f/ds^order of samples f (M, n) on a uniform grid of spacing h, by 7-point
    finite-difference stencils (centred inside, shifted one-sided near the ends)."""
    m = len(f)
    k = np.arange(m)
    start = np.clip(k - _STENCIL // 2, 0, m - _STENCIL)
    shift = k - start                                     # position of node k in its window
    weights = np.array([_fd_weights(np.arange(_STENCIL) - c, order) for c in range(_STENCIL)])
    windows = f[start[:, None] + np.arange(_STENCIL)]     # (M, stencil, n)
    return np.einsum('kj,kjn->kn', weights[shift], windows) / h**order


def _path_samples(path, s):
    """P, O, dP/ds, dO/ds of R at the arc lengths s (M,), each (M, 3)."""
    (p, o), (dp, do) = path.tangents(s)
    return tuple(np.asarray(a, float).reshape(len(s), 3) for a in (p, o, dp, do))


class PoseSolver:
    """Configurations q (axis order, m / rad) that put the tool at single poses (tool tip P,
    unit tool axis O, workpiece frame), each from a start configuration, moving only the
    active axes of `settings`: :meth:`weighted`, the stroke-weighted least-norm Newton solve
    of :func:`initial_configuration` (every axis moves in proportion to its stroke; strokes
    are not enforced), and :meth:`inside`, the configuration inside the strokes closest to
    the pose (bounded least squares)."""

    def __init__(self, kinematics: Kinematics, machine: MachineConfig, settings: RedundancySettings | None = None):
        self.settings = settings or RedundancySettings()
        self.resolver = _Resolver(kinematics, machine, self.settings)
        self.kinematics, self.machine = kinematics, machine
        active = [machine.axes[i] for i in self.resolver.active]
        self.lower = np.array([-np.inf if a.stroke is None else a.stroke[0] for a in active])
        self.upper = np.array([np.inf if a.stroke is None else a.stroke[1] for a in active])

    def weighted(self, p, o, start) -> tuple[np.ndarray, float, float]:
        """q from `start` by the stroke-weighted Newton solve, its position error (m) and
        orientation error (rad): both <= 1e-14 when it converged."""
        q, ep, eo, _ = self.resolver.project(p, o, np.array(start, dtype=float), self.settings.initial_iterations,
                                             1e-14, weighted=True)
        return q, ep, eo

    def inside(self, p, o, start) -> tuple[np.ndarray, float, float]:
        """The configuration inside the strokes nearest to the pose (least squares of the
        position and tool-axis errors), its position error (m) and orientation error (rad):
        both ~0 when the pose is reachable inside the strokes. Solved from `start` moved into
        the strokes and from it with each unlimited axis turned by a quarter, a half and
        three quarters of a turn (at a turn of the table where a pose lies straight beside
        the reach of the linear axes, turning it is a saddle of the error: a start there
        never turns). The best of these local solutions: a larger error is evidence, not
        proof."""
        active = self.resolver.active
        q = np.array(start, dtype=float)
        o = np.asarray(o, dtype=float)

        def errors(x):
            q[active] = x
            tip, axis = self.kinematics.forward(q)
            return np.concatenate((tip - p, axis - o))

        def jacobian(x):
            q[active] = x
            return self.kinematics.forward_and_jacobian(q)[2][:, active]

        first = np.clip(q[active], self.lower, self.upper)
        turns = [turn * (np.arange(len(first)) == k)
                 for k in np.flatnonzero(np.isinf(self.upper)) for turn in (0.5 * np.pi, np.pi, -0.5 * np.pi)]
        starts = [first] + [first + turn for turn in turns]
        from scipy.optimize import least_squares   # here: a node that only imports this need not (~0.8 s)
        best = None
        for x0 in starts:
            # dogbox: ~10 evaluations here where scipy's default trust region takes hundreds
            fit = least_squares(errors, x0, jacobian, method='dogbox', bounds=(self.lower, self.upper),
                                xtol=1e-12, ftol=1e-12, gtol=1e-12)
            if best is None or fit.cost < best.cost:
                best = fit
            if best.cost < 1e-24:              # reached: errors ~1e-12 or below
                break
        q[active] = best.x
        tip, axis = self.kinematics.forward(q)
        return q, float(np.linalg.norm(tip - p)), _angle(axis, o)


def initial_configuration(path, kinematics: Kinematics, machine: MachineConfig,
                          settings: RedundancySettings | None = None, start=None) -> np.ndarray:
    """q0 matching R(0): :meth:`PoseSolver.weighted` from `start` (default: the machine's
    home), dq = W (J_t W)^+ e_t per Newton step (W = diag of the half-strokes,
    `unlimited_scale` for c_f), so each active axis moves in proportion to its stroke and
    the fine axes stay near home. Raises ResolutionFailed('unreachable'), a ValueError, when
    R(0) cannot be reached with the active axes (e.g. a z offset with only x-y axes active)."""
    pd, od = _path_samples(path, np.zeros(1))[:2]
    q, ep, eo = PoseSolver(kinematics, machine, settings).weighted(pd[0], od[0],
                                                                   machine.home if start is None else start)
    if ep > 1e-12 or eo > 1e-12:
        raise ResolutionFailed('unreachable', f'cannot reach R(0) with the active axes: residual '
                               f'{ep:.3g} m, {eo:.3g} rad', 0.0)
    return q


def _task_rank(res: _Resolver, q) -> int:
    sig = np.linalg.svd(res.task(q)[3], compute_uv=False)
    return int(np.count_nonzero(sig > 1e-9 * sig[0])) if sig[0] > 0 else 0


def _interpreted(res: _Resolver, _chains, target, ds: float, q, qs, dq, progress) -> tuple[float, float]:
    """The RK4 loop of Algorithm 1 in Python, on the Kinematics' own (Pinocchio) calls: for
    a machine whose chains do not pack (resolved_rate.integrate has the contract)."""
    settings = res.settings
    at = lambda j: tuple(a[j] for a in target)           # noqa: E731
    q, ep, eo, task = res.project(target[0][0], target[1][0], q, 0, 0.0)
    max_ep, max_eo = ep, eo
    qs[0] = q
    n_steps = len(qs) - 1
    for k in range(n_steps):
        progress[0] = k
        k1, dq[k] = res.rate(at(2 * k), q, task)
        k2 = res.rate(at(2 * k + 1), q + 0.5 * ds * k1)[0]
        k3 = res.rate(at(2 * k + 1), q + 0.5 * ds * k2)[0]
        k4 = res.rate(at(2 * k + 2), q + ds * k3)[0]
        q = q + (k1 + 2.0 * k2 + 2.0 * k3 + k4) * (ds / 6.0)
        q, ep, eo, task = res.project(target[0][2 * k + 2], target[1][2 * k + 2], q,
                                      settings.projection_iterations, settings.projection_tolerance)
        max_ep, max_eo = max(max_ep, ep), max(max_eo, eo)
        qs[k + 1] = q
    progress[0] = n_steps
    dq[-1] = res.rate(at(2 * n_steps), q, task)[1]
    return max_ep, max_eo


def _compiled(res: _Resolver, chains, target, ds: float, q, qs, dq, progress) -> tuple[float, float]:
    """The same loop compiled (trajectory/resolved_rate.py), on the packed chains."""
    from trajectory import resolved_rate      # here: numba's import (~0.5 s) only where a path is resolved
    settings = res.settings
    stroke = (res.limited.astype(np.int64), np.ascontiguousarray(res.centre, float),
              np.ascontiguousarray(res.half, float))
    gains = (float(settings.beta), float(settings.drift_gain), float(settings.manipulability_threshold),
             float(settings.damping_max))
    return resolved_rate.integrate(chains, res.active.astype(np.int64), stroke, gains, int(res.rank),
                                   int(settings.projection_iterations), float(settings.projection_tolerance),
                                   tuple(np.ascontiguousarray(a, float) for a in target), float(ds),
                                   np.ascontiguousarray(q, float), qs, dq, progress)


def resolve(path, kinematics: Kinematics, machine: MachineConfig,
            settings: RedundancySettings | None = None, q0=None) -> Resolution:
    """Algorithm 1 of the thesis: integrate Eq. 3.27 with RK4 (Eq. 3.24) from q0 over
    s in [0, path.length] in N = max(6, ceil(S / settings.step)) equal steps; see the
    module docstring for the rate, the projection and the derivative outputs. Raises
    ResolutionFailed (a ValueError naming the problem and where) when the integration breaks
    down: the path leaves the reach of the strokes or a singular configuration."""
    settings = settings or RedundancySettings()
    length = float(path.length)
    if not (math.isfinite(length) and length > 0):
        raise ValueError(f'path length must be positive and finite, got {length!r}')
    res = _Resolver(kinematics, machine, settings)
    if q0 is None:
        q = initial_configuration(path, kinematics, machine, settings)
    else:
        q = np.array(q0, dtype=float)
        if q.shape != (len(machine.axis_names),) or not np.all(np.isfinite(q)):
            raise ValueError(f'q0 must be {len(machine.axis_names)} finite axis positions')
    res.rank = _task_rank(res, q)
    # at least one stencil's worth of nodes for the derivative outputs
    n_steps = max(_STENCIL - 1, math.ceil(length / settings.step - 1e-9))
    ds = length / n_steps
    s = np.arange(n_steps + 1) * ds
    s[-1] = length
    half = np.arange(2 * n_steps + 1) * (0.5 * ds)       # R at the grid and the RK4 midpoints
    half[-1] = length
    target = _path_samples(path, half)
    qs, dq = np.empty((n_steps + 1, len(q))), np.empty((n_steps + 1, len(q)))
    chains = kinematics.packed_chains()
    integrate = _compiled if chains is not None else _interpreted
    progress = np.zeros(1, np.int64)
    try:
        max_ep, max_eo = integrate(res, chains, target, ds, q, qs, dq, progress)
    except np.linalg.LinAlgError:       # "Singular matrix": say why, and where
        raise _failure(machine, s, qs[:int(progress[0]) + 1], path) from None
    bad = ~(np.isfinite(qs).all(axis=1) & np.isfinite(dq).all(axis=1))
    if bad.any():                       # the rate blew up without a LinAlgError
        raise _failure(machine, s, qs[:int(np.argmax(bad)) + 1], path)
    return Resolution(s, qs, dq, _along_s(dq, ds, 1), _along_s(dq, ds, 2), max_ep, max_eo,
                      tuple(machine.axis_names))
