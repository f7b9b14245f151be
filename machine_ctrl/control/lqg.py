"""LQG position control of one axis of Sörnmo's piezo micro manipulator (seed
004_33b29b0855b96c5a, section 2.4), designed from an identified discrete model (Eqs. 2.1-2.2,
machine_ctrl/identification/subspace.py), as plain numeric functions and one controller:

* state feedback u_k = -L x^_k - l_i x_i,k + l_r r_k (Eq. 2.4, u_ff = l_r r_k), L_e = [L l_i]
  minimizing sum z'Qz + u'Ru (Eq. 2.5) over z = [x, x_i] with the integral state of Eq. (2.9)
  discretized by forward Euler, x_i,k+1 = x_i,k + h (r_k - y_k); the thesis's weights Q = I,
  R = 2.5 (section 2.6);
* l_r such that the closed loop without the integral action has static gain 1 (section 2.4:
  "tuned such that the gain is 1");
* the Kalman filter of Eqs. (2.6)-(2.7) with the constant disturbance state of Eq. (2.8) on
  the output (y = C x + D u + x^e), its gain the steady state of the identified noise
  covariances (the identification "provides the Kalman gain"); the disturbance state's own
  drift is assumed (:data:`DISTURBANCE_DRIFT`);
* a notch on the reference at the axis's eigenfrequency (the y axis of section 2.6), a
  biquad by the bilinear transform pre-warped at its centre.

All of it is linear and deterministic; :class:`LqgController` runs it step by step, and
:class:`LqgLaw` is it behind the control-law interface for a machine's piezo axis.
:func:`design` answers with a status and a reason (a model it cannot control, a notch it
cannot place), never an exception.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import LinAlgError, solve_discrete_are

from machine_ctrl.control.filters import Biquad, tustin
from machine_ctrl.control.law import Parameter, gains_change_problem, retune_checked
from machine_ctrl.identification.subspace import NoiseCovariance, StateSpaceModel, balanced
from machine_ctrl.model import modal
from machine_ctrl.model.config import AxisConfig, LqgGains

Q_WEIGHT, R_WEIGHT = 1.0, 2.5          # Q = I, R = 2.5, Sörnmo section 2.6
# assumed: the disturbance state drifts with a variance per sample of 1 % of the measurement
# noise's: slow against the noise (the thesis adds it for the static gain, not to track fast
# disturbances) and still converging within a few hundred samples
DISTURBANCE_DRIFT = 0.01


@dataclass(frozen=True)
class LqgDesign:
    """The controller of the module doc for the model (phi, gamma, c, d) at `period`."""
    phi: np.ndarray
    gamma: np.ndarray          # (n,)
    c: np.ndarray              # (n,)
    d: float
    period: float
    feedback: np.ndarray       # L, (n,)
    integral_gain: float       # l_i
    reference_gain: float      # l_r
    observer_gain: np.ndarray  # K of the filter with the disturbance state, (n + 1,)


def lq_gains(phi, gamma, c, d: float, period: float, q: float = Q_WEIGHT, r: float = R_WEIGHT):
    """(L, l_i): the LQ state feedback of Eq. (2.5) on [x, x_i] (module doc)."""
    n = phi.shape[0]
    a = np.zeros((n + 1, n + 1))
    a[:n, :n], a[n, :n], a[n, n] = phi, -period * c, 1.0
    b = np.concatenate([gamma, [-period * d]])[:, None]
    p = solve_discrete_are(a, b, q * np.eye(n + 1), np.array([[r]]))
    gains = np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)[0]
    return gains[:n], float(gains[n])


def reference_gain(phi, gamma, c, d: float, feedback) -> float:
    """l_r with unit static gain of y/r for u = -L x + l_r r (module doc); ValueError when
    that loop has no static gain to scale."""
    n = phi.shape[0]
    closed = np.linalg.solve(np.eye(n) - phi + np.outer(gamma, feedback), gamma)
    static = float(c @ closed + d * (1.0 - feedback @ closed))
    if not (math.isfinite(static) and abs(static) > 1e-12):
        raise ValueError(f'the loop without integral action has static gain {static:g}')
    return 1.0 / static


def kalman_gain(phi, c, process, measurement, cross, drift: float = DISTURBANCE_DRIFT) -> np.ndarray:
    """Steady-state predictor gain of Eq. (2.6) for [x, x^e] (module doc): process noise
    `process` on x, `drift` x measurement on x^e, measurement noise `measurement`, cross term
    `cross` between x's noise and the measurement's."""
    n = phi.shape[0]
    a = np.eye(n + 1)
    a[:n, :n] = phi
    ce = np.concatenate([c, [1.0]])
    r = float(np.asarray(measurement).reshape(-1)[0])
    qe = np.zeros((n + 1, n + 1))
    qe[:n, :n], qe[n, n] = process, drift * r
    se = np.zeros((n + 1, 1))
    se[:n, 0] = np.asarray(cross).reshape(-1)
    p = solve_discrete_are(a.T, ce[:, None], qe, np.array([[r]]), s=se)
    return ((a @ p @ ce + se[:, 0]) / (ce @ p @ ce + r))


def filter_step(estimate, phi, gamma, c, d: float, gain, u: float, y: float) -> np.ndarray:
    """One step of the Kalman predictor of Eq. (2.6) with the constant output disturbance of
    Eq. (2.8): [x^, x^e] for the next sample from input `u` and measurement `y`."""
    n = phi.shape[0]
    x = estimate[:n]
    innovation = y - (c @ x + d * u + estimate[n])
    return np.concatenate([phi @ x + gamma * u, [estimate[n]]]) + gain * innovation


class Status(enum.Enum):
    OK = 'ok'
    FAILED = 'failed'


@dataclass(frozen=True)
class LqgResult:
    status: Status
    reason: str
    design: LqgDesign | None = None

    @property
    def ok(self) -> bool:
        return self.status is Status.OK


def design(phi, gamma, c, d: float, period: float, process, measurement, cross,
           q: float = Q_WEIGHT, r: float = R_WEIGHT) -> LqgResult:
    """The module doc's controller for the model and its noise covariances, or the reason why not."""
    phi, gamma, c = np.asarray(phi, float), np.asarray(gamma, float).reshape(-1), np.asarray(c, float).reshape(-1)
    if not (q > 0 and r > 0 and period > 0):
        return LqgResult(Status.FAILED, f'weights and period must be positive, got Q = {q}, R = {r}, h = {period}')
    try:
        feedback, integral = lq_gains(phi, gamma, c, d, period, q, r)
        lr = reference_gain(phi, gamma, c, d, feedback)
        kalman = kalman_gain(phi, c, process, measurement, cross)
    except (LinAlgError, ValueError, ZeroDivisionError) as exc:
        return LqgResult(Status.FAILED, f'no LQG design for this model: {" ".join(str(exc).split()) or type(exc).__name__}')
    if not (math.isfinite(lr) and np.isfinite(feedback).all() and np.isfinite(kalman).all()):
        return LqgResult(Status.FAILED, 'no LQG design for this model: the gains are not finite')
    return LqgResult(Status.OK, '', LqgDesign(phi, gamma, c, float(d), period, feedback, integral, lr, kalman))


def notch(frequency: float, period: float, depth: float = 0.0, width: float = 0.5) -> Biquad:
    """The biquad (s^2 + 2 depth zeta w s + w^2) / (s^2 + 2 zeta w s + w^2), zeta = width / 2,
    by the bilinear transform pre-warped at w = 2 pi `frequency` (control/filters.py): gain
    `depth` at the centre (0: a zero), 1 at DC and far from it. ValueError for a centre outside
    (0, Nyquist)."""
    if not 0.0 < frequency < 0.5 / period:
        raise ValueError(f'notch at {frequency!r} Hz: must lie within (0, {0.5 / period:g}) Hz, the Nyquist band')
    w, zeta = 2 * math.pi * frequency, width / 2
    return tustin([1.0, 2 * depth * zeta * w, w * w], [1.0, 2 * zeta * w, w * w], period, prewarp=w)


class LqgController:
    """The LQG law of a design, one step per sample: `step(r, y)` -> u (module doc), the
    reference through an optional notch (a Biquad)."""

    def __init__(self, design_: LqgDesign, reference_notch: Biquad | None = None):
        self.design, self.notch = design_, reference_notch
        self.reset()

    def reset(self) -> None:
        n = self.design.phi.shape[0]
        self.estimate = np.zeros(n + 1)            # [x^, x^e]
        self.integral = 0.0
        if self.notch is not None:
            self.notch.reset()

    def step(self, r: float, y: float) -> float:
        g = self.design
        r = r if self.notch is None else self.notch.step(r)
        x = self.estimate[:g.phi.shape[0]]
        u = float(-g.feedback @ x - g.integral_gain * self.integral + g.reference_gain * r)
        self.estimate = filter_step(self.estimate, g.phi, g.gamma, g.c, g.d, g.observer_gain, u, y)
        self.integral += g.period * (r - y)
        return u


class LqgLaw:
    """The LQG behind the control-law interface (machine_ctrl/control/law.py) for a piezo axis:
    designed at the control period from the controllers' model of the axis (drive.modes and
    drive.real_pole: the identified model of section 2.3 in modal form, ``machine-ctrl
    identify AXIS --out``; hw_sim simulates plant.modes, the truth) in its balanced
    realization (identification/subspace.py), with Q = state_weight I and R = control_weight
    (Eq. 2.5); the Kalman filter's noise: an input disturbance of
    `process_noise` per period and the sensor's noise (plant.sensor_noise: the truth, read as
    the sensor's data sheet would give it) plus its quantization; the
    reference notch at `notch_frequency` (section 2.6). Nothing is live: a new design is a new law."""

    parameters = (
        Parameter('state_weight', '1', 'Q = state_weight I on [x, x_i], Eq. (2.5)'),
        Parameter('control_weight', '1', 'R, Eq. (2.5)'),
        Parameter('process_noise', 'm', "the model's input disturbance, std per control period (Kalman filter)"),
        Parameter('notch_frequency', 'Hz', "the reference notch's centre, section 2.6 (0: none)"),
        Parameter('notch_width', '1', "2 zeta of the notch's poles"),
    )

    @classmethod
    def from_axis(cls, gains: LqgGains, axis: AxisConfig, period: float) -> LqgLaw:
        plant, drive = axis.plant, axis.drive
        if drive.type != 'piezo' or not drive.modes:
            raise ValueError(f'axis {axis.name}: the lqg law needs a piezo drive with drive.modes (its model)')
        if plant is None:       # the sensor's noise for the Kalman filter is read from the plant (class doc)
            raise ValueError(f'axis {axis.name}: the lqg law needs the plant section (its sensor noise)')
        a, b, c = modal.state_space([(m.omega, m.zeta) for m in drive.modes], drive.real_pole)
        phi, gamma = modal.held(a, b, period)
        n = len(gamma)
        measurement = plant.sensor_noise ** 2 + axis.sensor_resolution ** 2 / 12.0     # noise + quantization
        model, noise = balanced(StateSpaceModel(phi, gamma[:, None], c[None, :], np.zeros((1, 1)), period),
                                NoiseCovariance(np.outer(gamma, gamma) * gains.process_noise ** 2,
                                                np.array([[measurement]]), np.zeros((n, 1))))
        result = design(model.a, model.b, model.c, 0.0, period, noise.process, noise.measurement, noise.cross,
                        q=gains.state_weight, r=gains.control_weight)
        if not result.ok:
            raise ValueError(f'axis {axis.name}: {result.reason}')
        reference_notch = None
        if gains.notch_frequency > 0.0:
            try:
                reference_notch = notch(gains.notch_frequency, period, width=gains.notch_width)
            except ValueError as exc:
                raise ValueError(f'axis {axis.name}: {exc}') from None
        return cls(gains, LqgController(result.design, reference_notch))

    def __init__(self, gains: LqgGains, controller: LqgController):
        self.gains, self.controller = gains, controller

    def retune_problem(self, gains: LqgGains) -> str | None:
        return gains_change_problem(self, gains)

    def retune(self, gains: LqgGains) -> None:
        retune_checked(self, gains)
        self.gains = gains

    def reset(self) -> None:
        self.controller.reset()

    def step(self, x_r: float, v_r: float, a_r: float, x: float, v: float, acc: float = 0.0) -> float:
        return self.controller.step(x_r, x)
