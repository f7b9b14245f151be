"""Adaptive feed-rate force control in robotic machining (Sörnmo, seed
004_33b29b0855b96c5a, Ch. 5, Fig. 5.2): the robot's feed velocity reference v_r is set so
that the machining force follows its reference f_r, the controller adapted to the material
removal parameter D_f estimated on line. As plain numeric functions and one controller:

* the robot's velocity dynamics G_v (Eq. 5.1): an identified discrete model from v_r to the
  measured velocity v (machine_ctrl/identification/subspace.py, as §5.2 identifies it),
  with its Kalman filter (Eqs. 5.7-5.8) extended by a constant disturbance state on the
  output for the static gain (§5.2; :func:`machine_ctrl.control.lqg.kalman_gain`);
* the force state of Eq. (5.9), x_f = f, discretized with v held over the period:
  x_f,k+1 = a x_f,k + (1 - a) D_f v_k, a = exp(-K_f h / D_f); with v_k = C x_k + D u_k this is
  the augmented model of Eqs. (5.11)-(5.12) in discrete time;
* the integral state of Eq. (5.15), x_i,k+1 = x_i,k + h (f_r - f_k) (forward Euler), and the
  LQ state feedback of Eqs. (5.13)-(5.14) on [x, x_f, x_i]: v_r = -L [x^, x_f] - l_i x_i + l_r f_r,
  l_r giving the loop without integral action a static gain of 1;
* the estimate of D_f by recursive least squares with forgetting (§5.2 uses the RLS of Eqs.
  3.5-3.7: machine_ctrl.control.midranging.RLS) on f_k+1 = a f_k + b v_k, whence
  D_f = b / (1 - a) — the ratio the data determine even at a constant feed (then b / (1 - a) =
  f / v); the controller is activated once the estimate's covariance, relative to the
  estimate, passes below a threshold (§5.2; :attr:`RemovalEstimator.spread`), before that
  v_r is a constant conservative feed (§5.3); from then on it is designed again from the
  estimate whenever the estimate has moved by more than a fraction
  (:attr:`AdaptationConfig.redesign`) from the one it was designed for ("continuously
  adapt", §5.2).

:func:`design` answers with a status and a reason, never an exception. Units: m/s, N, s.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import LinAlgError, solve_discrete_are

from machine_ctrl.control.lqg import filter_step, kalman_gain
from machine_ctrl.control.midranging import RLS
from machine_ctrl.identification.subspace import NoiseCovariance, StateSpaceModel


@dataclass(frozen=True)
class Weights:
    """Q = diag(state I, force, integral) and R of Eq. (5.14), in SI units (N, N s, m/s).
    assumed, all of them: §5.3 only says the weights were chosen so that a force deviation
    costs much ("resulting in a fast force response"). A force error of 1 N weighs as much as
    a feed of 1 mm/s (r = 1 / (1 mm/s)^2), the integral of the force error as that of a
    1 N error held 0.1 s, the robot's own states nothing; chosen so before any run (the
    experiment prints what slower loops, R x 10 and x 100, do)."""
    state: float = 0.0
    force: float = 1.0              # 1/N^2
    integral: float = 100.0         # 1/(N s)^2
    control: float = 1e6            # 1/(m/s)^2


@dataclass(frozen=True)
class FeedForceDesign:
    """The controller of the module doc for one D_f."""
    model: StateSpaceModel
    stiffness: float                # K_f, N/m
    removal: float                  # D_f, N s/m
    feedback: np.ndarray            # L over [x, x_f], (n + 1,)
    integral_gain: float            # l_i
    reference_gain: float           # l_r


class Status(enum.Enum):
    OK = 'ok'
    FAILED = 'failed'


@dataclass(frozen=True)
class DesignResult:
    status: Status
    reason: str
    design: FeedForceDesign | None = None

    @property
    def ok(self) -> bool:
        return self.status is Status.OK


def force_model(model: StateSpaceModel, stiffness: float, removal: float) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the augmented model over [x, x_f] (module doc), the input v_r."""
    n = model.order
    a = math.exp(-stiffness * model.period / removal)
    c, d = model.c[0], float(model.d[0, 0])
    big_a = np.zeros((n + 1, n + 1))
    big_a[:n, :n] = model.a
    big_a[n, :n], big_a[n, n] = (1.0 - a) * removal * c, a
    big_b = np.concatenate([model.b[:, 0], [(1.0 - a) * removal * d]])
    return big_a, big_b


def design(model: StateSpaceModel, stiffness: float, removal: float, weights: Weights = Weights()) -> DesignResult:
    """The module doc's LQ law for G_v = `model`, K_f = `stiffness` and D_f = `removal`, or the
    reason why there is none (the Kalman filter does not depend on D_f:
    :class:`FeedForceController` designs it once)."""
    if not (math.isfinite(stiffness) and stiffness > 0 and math.isfinite(removal) and removal > 0):
        return DesignResult(Status.FAILED, f'K_f and D_f must be positive, got {stiffness!r} N/m and {removal!r} N s/m')
    n, h = model.order, model.period
    a, b = force_model(model, stiffness, removal)
    big_a = np.zeros((n + 2, n + 2))          # [x, x_f, x_i]
    big_a[:n + 1, :n + 1], big_a[n + 1, n], big_a[n + 1, n + 1] = a, -h, 1.0
    big_b = np.concatenate([b, [0.0]])[:, None]
    q = np.diag([weights.state] * n + [weights.force, weights.integral])
    r = np.array([[weights.control]])
    try:
        p = solve_discrete_are(big_a, big_b, q, r)
        gains = np.linalg.solve(r + big_b.T @ p @ big_b, big_b.T @ p @ big_a)[0]
        feedback = gains[:n + 1]
        closed = np.linalg.solve(np.eye(n + 1) - a + np.outer(b, feedback), b)   # x_f / (l_r f_r) at rest
        static = float(closed[n])
    except (LinAlgError, ValueError) as exc:
        return DesignResult(Status.FAILED, f'no LQ design for D_f = {removal:.4g} N s/m: '
                                           f'{" ".join(str(exc).split()) or type(exc).__name__}')
    if not (abs(static) > 1e-12 and np.isfinite(gains).all()):
        return DesignResult(Status.FAILED, f'no LQ design for D_f = {removal:.4g} N s/m: the gains are not finite')
    return DesignResult(Status.OK, '', FeedForceDesign(model, float(stiffness), float(removal), feedback,
                                                      float(gains[n + 1]), 1.0 / static))


# assumed: RLS's start covariance P0 = p0 I. With the regressors' scales (f ~ 20 N, v ~ 6 mm/s)
# it weighs the start value of b like ~30 samples and that of a like none: the first samples
# move the estimate at once
P0 = 1e3
# assumed: the spread is read after this many samples (before, one or two give a tiny P by chance)
SPREAD_START = 10


class RemovalEstimator:
    """D_f from (f_k, v_k, f_k+1) by RLS with forgetting (module doc). `spread` is what §5.2
    thresholds, the estimate's covariance relative to the estimate: the delta method on RLS's P
    scaled by the prediction errors' mean square (over all samples at first, then over the
    forgetting factor's memory); nan until SPREAD_START samples have been seen. It is an
    index, not the estimate's scatter: the JR3's noise is in the regressor f_k and in the
    target f_k+1, so the prediction errors are correlated from one sample to the next, which
    P does not know (at a constant 6 mm/s in 3 N s/mm, 40 seeds: 2.3 / 1.0 / 0.61 % after 78 /
    300 / 1000 periods, against a scatter of 0.19 / 0.073 / 0.034 %)."""

    def __init__(self, period: float, stiffness: float, initial: float, forgetting: float, p0: float = P0):
        a0 = math.exp(-stiffness * period / initial)          # the model of D_f = initial
        self.rls = RLS((a0, (1.0 - a0) * initial), p0, forgetting)
        self.reset()

    def reset(self) -> None:
        self.rls.reset()
        self.samples, self.error_variance = 0, 0.0

    @property
    def value(self) -> float:
        a, b = self.rls.theta
        return b / (1.0 - a) if a < 1.0 else math.nan

    @property
    def spread(self) -> float:
        a, b = self.rls.theta
        if self.samples < SPREAD_START or not a < 1.0:
            return math.nan
        grad = (b / (1.0 - a) ** 2, 1.0 / (1.0 - a))
        p = self.rls.P
        var = self.error_variance * sum(grad[i] * p[i][j] * grad[j] for i in range(2) for j in range(2))
        value = self.value
        return math.sqrt(max(var, 0.0)) / abs(value) if value else math.nan

    def update(self, force: float, velocity: float, next_force: float) -> float:
        a, b = self.rls.theta
        error = next_force - a * force - b * velocity
        self.samples += 1
        # the mean square over the samples so far, then over the forgetting factor's memory
        weight = max(1.0 / self.samples, 1.0 - self.rls.forgetting)
        self.error_variance += weight * (error * error - self.error_variance)
        self.rls.update((force, velocity), next_force)
        return self.value


@dataclass(frozen=True)
class AdaptationConfig:
    """When the controller starts and how it follows D_f (module doc)."""
    initial_removal: float = 1e3    # N s/m: D_f's start value, "set to 1" (§5.3, §5.5; read as N s/mm)
    initial_feed: float = 6e-3      # m/s, the conservative constant feed before activation (§5.3)
    forgetting: float = 0.995       # assumed: lambda, a memory of ~200 periods (0.8 s); the seed
    # states none. A step of D_f is followed in seconds (the §5.3 run's doubling: half of it after
    # 1 s, within 2 % after ~3 s): the noise-driven regression moves slower than the memory says
    threshold: float = 0.02         # assumed: activated once D_f's spread (RemovalEstimator) is
    # below 2 % ("a desired threshold", §5.2)
    redesign: float = 0.02          # assumed: designed again once D_f has moved 2 % from the last design
    adaptive: bool = True           # False: the design for initial_removal throughout (Fig. 5.6); the
    # estimator still runs, for the activation only (the seed disables it: when its fixed
    # controller started is not said)


class ControllerState(enum.Enum):
    ESTIMATING = 'estimating'       # the constant feed, D_f being estimated
    ACTIVE = 'active'               # the LQ force control


class FeedForceController:
    """The adaptive feed-rate force controller (module doc, Fig. 5.2), one step per ORCA
    period: `step(f, v, f_r)` with the measured force and velocity of the last period
    returns v_r for the next. `designs` counts the designs made, `refused` the estimates a
    design refused (the previous design stays)."""

    def __init__(self, model: StateSpaceModel, noise: NoiseCovariance, stiffness: float,
                 config: AdaptationConfig = AdaptationConfig(), weights: Weights = Weights()):
        self.model, self.stiffness = model, stiffness
        self.config, self.weights = config, weights
        self.estimator = RemovalEstimator(model.period, stiffness, config.initial_removal, config.forgetting)
        try:
            self.observer_gain = kalman_gain(model.a, model.c[0], noise.process, noise.measurement, noise.cross)
        except (LinAlgError, ValueError) as exc:
            raise ValueError(f'no Kalman filter for G_v: {" ".join(str(exc).split()) or type(exc).__name__}') from None
        first = design(model, stiffness, config.initial_removal, weights)
        if not first.ok:
            raise ValueError(first.reason)
        self._initial_design = first.design
        self.reset()

    def reset(self) -> None:
        self.estimator.reset()
        self.design = self._initial_design
        self.state = ControllerState.ESTIMATING
        n = self.model.order
        self.estimate = np.zeros(n + 1)        # [x^, x^e]
        self.integral = 0.0
        self.last_force: float | None = None
        self.last_input = self.config.initial_feed
        self.designs, self.refused = 1, 0
        self.activated_at: int | None = None
        self.k = 0

    def _observe(self, velocity: float) -> None:
        """Eqs. (5.7)-(5.8) for the last period's input and the measured velocity."""
        m = self.model
        self.estimate = filter_step(self.estimate, m.a, m.b[:, 0], m.c[0], float(m.d[0, 0]), self.observer_gain,
                                    self.last_input, velocity)

    def _adapt(self, removal: float, force: float, reference: float) -> None:
        """A new design for an estimate that has moved by more than `redesign`; bumpless: the
        integral state takes the value that gives the new gains the old gains' v_r now."""
        if not self.config.adaptive or not (math.isfinite(removal) and removal > 0.0):
            return
        if abs(removal - self.design.removal) <= self.config.redesign * self.design.removal:
            return
        before = self._law(force, reference)
        if self._redesign(removal):
            self._continue(before, force, reference)

    def _redesign(self, removal: float) -> bool:
        """The design for D_f = `removal`; False (counted in `refused`) when there is none."""
        result = design(self.model, self.stiffness, removal, self.weights)
        if not result.ok:
            self.refused += 1
            return False
        self.design, self.designs = result.design, self.designs + 1
        return True

    def _continue(self, u: float, force: float, reference: float) -> None:
        """Set the integral state so that the law gives `u` now (bumpless transfer)."""
        self.integral = 0.0
        self.integral = (self._law(force, reference) - u) / self.design.integral_gain

    def _law(self, force: float, reference: float) -> float:
        g, n = self.design, self.model.order
        state = np.concatenate([self.estimate[:n], [force]])
        return float(-g.feedback @ state - g.integral_gain * self.integral + g.reference_gain * reference)

    def step(self, force: float, velocity: float, reference: float) -> float:
        if self.last_force is not None:
            removal = self.estimator.update(self.last_force, velocity, force)
        else:
            removal = self.estimator.value
        self._observe(velocity)
        if self.state is ControllerState.ESTIMATING:
            spread = self.estimator.spread
            if math.isfinite(spread) and spread < self.config.threshold:
                self.state, self.activated_at = ControllerState.ACTIVE, self.k
                if self.config.adaptive and math.isfinite(removal) and removal > 0.0:
                    self._redesign(removal)
                self._continue(self.last_input, force, reference)    # the constant feed goes on
        elif self.state is ControllerState.ACTIVE:
            self._adapt(removal, force, reference)
        if self.state is ControllerState.ACTIVE:
            u = self._law(force, reference)
            self.integral += self.model.period * (reference - force)
        else:
            u = self.config.initial_feed
        self.last_force, self.last_input = force, u
        self.k += 1
        return u
