"""Redundancy resolution of a redundant machine along a toolpath (Yuen thesis §3.3-3.8,
Algorithm 1): axis positions q[n] and their geometric derivatives dq/ds, d²q/ds², d³q/ds³
at fixed displacement steps s[n] = n Δs.

The toolpath R(s) = [P(s); O(s)] (Eq. 3.12) is any object with ``length`` (m),
``evaluate(s) -> (P, O)`` and ``derivatives(s, order) -> (d^kP/ds^k, d^kO/ds^k)``.

Resolved rate (Eq. 3.27, with the errata of seed-notes.md applied)::

    dq/ds = g(s, q) = J_t^# (dR_t/ds + K_e e_t) - beta (I - J_t^# J_t) grad H(q)

* J_t is the 5 x n task Jacobian [dP/dq; B^T dO/dq] (B = orthonormal basis of the plane
  normal to the current tool axis O(q), as :func:`machine_ctrl.kinematics.task_jacobian`):
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
term vanishes there and q' = g0(s, q), q'' = d/ds g0, q''' = d²/ds² g0 with g0 the rate without
the K_e term. These total derivatives are evaluated as directional differences of g0 along
the second-order Taylor curve c(t) = (s + t, q + t q' + t²/2 q''): d/dt g0(c(t)) at t=0 is q''
and d²/dt² g0(c(t)) is q''' (c''(0) carries the q'' term). Central differences of step
``derivative_step`` (one-sided 2nd-order stencils within one step of the path ends), so the
truncation error is O(h²) (relative ~h²/(12 ρ²) for a path with radius of curvature ρ) and
the round-off ~eps/h² relative to |g0|. For the 4 mm circle both are < 1e-7 relative.
Caveat: mu of Eq. 3.22 is only C¹ at w = w0, so q''' jumps where w crosses w0.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from machine_ctrl.config import MachineConfig
from machine_ctrl.kinematics import Kinematics


@dataclass(frozen=True)
class RedundancySettings:
    """Tuning of the resolution. Lengths in m, angles in rad."""
    # assumed: not stated in the thesis (seed-notes.md). 20 µm keeps the stiffest nullspace
    # mode (rate beta/h_f² = 5e3 1/m for the 100 µm fine strokes) at 0.1 of RK4's real-axis
    # stability limit 2.79, and gives 1257 points per turn of the 4 mm circle.
    step: float = 20e-6
    # assumed: beta (m², because grad H is in 1/m). On a unit-speed path the fine axis settles
    # where its gradient 2u/(h(1-u²)²) ~ 1/beta, i.e. |u| ~ 0.45 (45 µm of the 100 µm fine
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
    # Axis names that move; the others keep q0 (None: all axes).
    active_axes: tuple[str, ...] | None = None
    # Newton projection after each RK4 step (0 iterations: off).
    projection_iterations: int = 2
    projection_tolerance: float = 1e-13
    # assumed: finite-difference step of the derivative outputs; 1 µm balances the
    # O(h²/ρ²) truncation against the O(eps/h²) round-off for radii of curvature ~ mm.
    derivative_step: float = 1e-6
    # assumed: scale (rad) of an unlimited axis in the stroke-weighted Newton solve for q0;
    # comparable to 1/5 of a turn, so c_f is used only as much as the coarse axes.
    unlimited_scale: float = 1.0
    initial_iterations: int = 50

    def __post_init__(self):
        for name in ('step', 'drift_gain', 'manipulability_threshold', 'derivative_step',
                     'unlimited_scale'):
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
    """Same basis as machine_ctrl.kinematics.orientation_basis (written out: np.cross on
    3-vectors costs more than the rest of the rate evaluation)."""
    ox, oy, oz = o
    if abs(ox) < 0.9:       # helper e_x: e1 = o x e_x
        e1 = np.array([0.0, oz, -oy])
    else:                   # helper e_y: e1 = o x e_y
        e1 = np.array([-oz, 0.0, ox])
    e1 /= math.sqrt(e1 @ e1)
    e2 = np.array([oy * e1[2] - oz * e1[1], oz * e1[0] - ox * e1[2], ox * e1[1] - oy * e1[0]])
    return np.column_stack((e1, e2))


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    c = np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])
    return math.atan2(math.sqrt(c @ c), float(a @ b))


class _Resolver:
    def __init__(self, path, kinematics: Kinematics, machine: MachineConfig,
                 settings: RedundancySettings):
        self.path, self.kin, self.settings = path, kinematics, settings
        names = tuple(machine.axis_names)
        active = names if settings.active_axes is None else tuple(settings.active_axes)
        unknown = [a for a in active if a not in names]
        if unknown or not active:
            raise ValueError(f'active_axes: unknown axis names {unknown}' if unknown
                             else 'active_axes is empty')
        self.active = np.array([names.index(a) for a in names if a in active])
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
        self.centre, self.half = np.array(centre), np.array(half)
        self.scale = np.array(scale)
        self.rank = 5

    # --- pieces of Eq. 3.27 -------------------------------------------------------------
    def task(self, q):
        """P, O, B and the task Jacobian J_t restricted to the active axes."""
        p, o, jac = self.kin.forward_and_jacobian(q)
        b = _basis(o)
        jt = np.empty((5, len(self.active)))
        jt[:3] = jac[:3, self.active]
        jt[3:] = b.T @ jac[3:, self.active]
        return p, o, b, jt

    def damped_inverse(self, jt):
        """J_t^# of Eq. 3.21 with mu of Eq. 3.22 over the r reachable task directions."""
        u, sig, vt = np.linalg.svd(jt, full_matrices=False)
        r = self.rank
        sig = sig[:r]
        w = float(np.prod(sig))
        w0 = self.settings.manipulability_threshold
        mu = self.settings.damping_max * (1.0 - w / w0) ** 2 if w < w0 else 0.0
        return (vt[:r].T * (sig / (sig * sig + mu))) @ u[:, :r].T

    def grad_h(self, q_active):
        """Exact gradient of H = sum u²/(1-u²) (the cost whose gradient Eq. 3.20 prints)."""
        g = np.zeros(len(self.active))
        if len(self.limited):
            u = (q_active[self.limited] - self.centre) / self.half
            # a stage outside the stroke would flip the barrier's sign: clip just inside
            u = np.clip(u, -1.0 + 1e-9, 1.0 - 1e-9)
            g[self.limited] = 2.0 * u / (self.half * (1.0 - u * u) ** 2)
        return g

    def task_error(self, s, p, o, b):
        pd, od = self.path.evaluate(s)
        pd, od = np.asarray(pd, float), np.asarray(od, float)
        return np.concatenate((pd - p, b.T @ (od - o))), pd, od

    def rate(self, s, q, drift=True):
        """g(s, q) of Eq. 3.28: the full n-vector dq/ds (frozen axes 0)."""
        p, o, b, jt = self.task(q)
        jsharp = self.damped_inverse(jt)
        dp, do = self.path.derivatives(s, 1)
        v = np.concatenate((np.asarray(dp, float), b.T @ np.asarray(do, float)))
        if drift and self.settings.drift_gain:
            v = v + self.settings.drift_gain * self.task_error(s, p, o, b)[0]
        dqa = jsharp @ v
        beta = self.settings.beta
        if beta:
            grad = self.grad_h(q[self.active])
            dqa -= beta * (grad - jsharp @ (jt @ grad))
        dq = np.zeros_like(q)
        dq[self.active] = dqa
        return dq

    # --- Newton solves ----------------------------------------------------------------
    def project(self, s, q, iterations, tolerance, weighted=False):
        """Newton iterations q += J^# e_t on the active axes; returns q, position error (m),
        orientation error (rad) after the last evaluation."""
        q = q.copy()
        for it in range(iterations + 1):
            p, o, b, jt = self.task(q)
            e, pd, od = self.task_error(s, p, o, b)
            ep, eo = float(np.linalg.norm(pd - p)), _angle(o, od)
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
        return q, ep, eo


def _stencils(h):
    """(offsets, first-derivative weights, second-derivative weights) for the centred and the
    two one-sided stencils, all O(h²)."""
    centred = (np.array([-1.0, 0.0, 1.0]) * h, np.array([-0.5, 0.0, 0.5]) / h,
               np.array([1.0, -2.0, 1.0]) / h**2)
    forward = (np.array([0.0, 1.0, 2.0, 3.0]) * h, np.array([-1.5, 2.0, -0.5, 0.0]) / h,
               np.array([2.0, -5.0, 4.0, -1.0]) / h**2)
    backward = (-forward[0], -forward[1], forward[2])
    return centred, forward, backward


def _derivatives(res: _Resolver, s, q, length, stencils):
    """q', q'', q''' at (s, q) by directional differences of g0 along the Taylor curve."""
    h = res.settings.derivative_step
    centred, forward, backward = stencils
    if s - h < 0.0:
        offsets, w1, w2 = forward
    elif s + h > length:
        offsets, w1, w2 = backward
    else:
        offsets, w1, w2 = centred
    q1 = res.rate(s, q, drift=False)
    rates = [q1 if t == 0.0 else res.rate(s + t, q + t * q1, drift=False) for t in offsets]
    q2 = sum(w * r for w, r in zip(w1, rates))          # O(h²) first pass
    rates = [q1 if t == 0.0 else res.rate(s + t, q + t * q1 + 0.5 * t * t * q2, drift=False)
             for t in offsets]
    q2 = sum(w * r for w, r in zip(w1, rates))
    q3 = sum(w * r for w, r in zip(w2, rates))
    return q1, q2, q3


def initial_configuration(path, kinematics: Kinematics, machine: MachineConfig,
                          settings: RedundancySettings | None = None, start=None) -> np.ndarray:
    """q0 matching R(0): Newton iterations from `start` (default: the machine's home) with
    the stroke-weighted least-norm step dq = W (J_t W)^+ e_t (W = diag of the half-strokes,
    `unlimited_scale` for c_f), so each active axis moves in proportion to its stroke and
    the fine axes stay near home. Raises ValueError when R(0) cannot be reached with the
    active axes (e.g. a z offset with only x-y axes active)."""
    settings = settings or RedundancySettings()
    res = _Resolver(path, kinematics, machine, settings)
    q = np.array(machine.home if start is None else start, dtype=float)
    res.rank = _task_rank(res, q)
    q, ep, eo = res.project(0.0, q, settings.initial_iterations, 1e-14, weighted=True)
    if ep > 1e-12 or eo > 1e-12:
        raise ValueError(f'cannot reach R(0) with the active axes: residual {ep:.3g} m, '
                         f'{eo:.3g} rad')
    return q


def _task_rank(res: _Resolver, q) -> int:
    sig = np.linalg.svd(res.task(q)[3], compute_uv=False)
    return int(np.count_nonzero(sig > 1e-9 * sig[0])) if sig[0] > 0 else 0


def resolve(path, kinematics: Kinematics, machine: MachineConfig,
            settings: RedundancySettings | None = None, q0=None) -> Resolution:
    """Algorithm 1 of the thesis: integrate Eq. 3.27 with RK4 (Eq. 3.24) from q0 over
    s in [0, path.length] in N = ceil(S / settings.step) equal steps; see the module
    docstring for the rate, the projection and the derivative outputs."""
    settings = settings or RedundancySettings()
    length = float(path.length)
    if not (math.isfinite(length) and length > 0):
        raise ValueError(f'path length must be positive and finite, got {length!r}')
    res = _Resolver(path, kinematics, machine, settings)
    if q0 is None:
        q = initial_configuration(path, kinematics, machine, settings)
    else:
        q = np.array(q0, dtype=float)
        if q.shape != (len(machine.axis_names),) or not np.all(np.isfinite(q)):
            raise ValueError(f'q0 must be {len(machine.axis_names)} finite axis positions')
    res.rank = _task_rank(res, q)
    n_steps = max(1, math.ceil(length / settings.step - 1e-9))
    ds = length / n_steps
    s = np.arange(n_steps + 1) * ds
    s[-1] = length
    n = len(q)
    qs = np.empty((n_steps + 1, n))
    d1, d2, d3 = (np.empty((n_steps + 1, n)) for _ in range(3))
    stencils = _stencils(settings.derivative_step)
    _, ep, eo = res.project(0.0, q, 0, 0.0)
    max_ep, max_eo = ep, eo
    qs[0] = q
    for k in range(n_steps):
        sk = s[k]
        k1 = res.rate(sk, q)
        k2 = res.rate(sk + 0.5 * ds, q + 0.5 * ds * k1)
        k3 = res.rate(sk + 0.5 * ds, q + 0.5 * ds * k2)
        k4 = res.rate(sk + ds, q + ds * k3)
        q = q + (k1 + 2.0 * k2 + 2.0 * k3 + k4) * (ds / 6.0)
        q, ep, eo = res.project(s[k + 1], q, settings.projection_iterations,
                                settings.projection_tolerance)
        max_ep, max_eo = max(max_ep, ep), max(max_eo, eo)
        qs[k + 1] = q
    for k in range(n_steps + 1):
        d1[k], d2[k], d3[k] = _derivatives(res, s[k], qs[k], length, stencils)
    return Resolution(s, qs, d1, d2, d3, max_ep, max_eo, tuple(machine.axis_names))
