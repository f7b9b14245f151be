"""A voice-coil flexure stage (Ding's fast tool servo, seed 003_edeaa855566124b7) as one
linear time-invariant system, discretized exactly per control period: the model of
machine_ctrl/model/flexure_model.py (flexure, current loop, sensor low-pass, accelerometer,
current, sensor and accelerometer noise, the ground's motion at the flexure's root, an
external force). The noises are continuous white
noise through the model's columns (one-sided PSD 1/Hz; the columns carry the densities): their
effect over a period is drawn exactly, a Gaussian vector of the covariance Van Loan's matrix
exponential gives, from a numpy generator seeded from the plant's stream. The ADC's white
floor is the sensor's per-sample noise (``plant.sensor_noise``, hw_sim/plant.py
:class:`Sensor`); the accelerometer's ADC channel is :class:`Accelerometer`.

Loop delay (section 4.4.4, DAC -> ADC): the command computed from the sample at t_k acts from
t_k + loop_delay; until then the previous command holds. Both pieces are integrated exactly
(matrix exponentials of the augmented system); so is the external force, held over the period.
"""
from __future__ import annotations

import math
import random

import numpy as np
from scipy.linalg import expm

from hw_sim.plant import _Actuator, quantize
from machine_ctrl.model.config import AxisConfig
from machine_ctrl.model.flexure_model import continuous_model, held_input


def _noise_factor(a: np.ndarray, b_w: np.ndarray, t: float) -> np.ndarray:
    """F with F F' = Q, the covariance over `t` of the state driven by white noise of one-sided
    PSD 1/Hz (intensity 1/2) through b_w: Q = integral_0^t e^{A s} b_w b_w' e^{A' s} ds / 2, so
    that F z, z standard normal, is the period's exact noise. Van Loan's matrix exponential over
    a slice h = t / 2^k short enough that e^{-A h} stays moderate (its |eig| h <= 1: the
    formula subtracts products of e^{-A h} and e^{A h}, which loses every digit across the stiff
    poles of the current loop and the ground's roll-off over a whole period), then doubled k
    times: Q(2h) = Q(h) + e^{A h} Q(h) e^{A' h}."""
    n = a.shape[0]
    fastest = float(np.max(np.abs(np.linalg.eigvals(a)))) if n else 0.0
    k = math.ceil(math.log2(fastest * t)) if fastest * t > 1.0 else 0
    h = t / 2 ** k
    van_loan = np.zeros((2 * n, 2 * n))
    van_loan[:n, :n], van_loan[:n, n:], van_loan[n:, n:] = -a, 0.5 * b_w @ b_w.T, a.T
    e = expm(van_loan * h)
    phi, q = e[n:, n:].T, e[n:, n:].T @ e[:n, n:]
    for _ in range(k):
        q = q + phi @ q @ phi.T
        phi = phi @ phi
    q = 0.5 * (q + q.T)
    # factor the correlation matrix, then each state's own scale: rounding stays relative to
    # each state's standard deviation (they span from pm to m/s^2), a noiseless state gets none
    std = np.sqrt(np.clip(np.diag(q), 0.0, None))
    live = std > 0.0
    correlation = q[np.ix_(live, live)] / np.outer(std[live], std[live])
    values, vectors = np.linalg.eigh(0.5 * (correlation + correlation.T))
    factor = np.zeros((n, n))
    factor[np.ix_(live, np.arange(live.sum()))] = std[live, None] * vectors * np.sqrt(np.clip(values, 0.0, None))
    return factor


class FlexureAxis(_Actuator):
    """The stage of the module doc; `position` is the true tool position x1, `sensed` the
    sensor's output y (before its per-sample noise and quantization), `acceleration_sensed`
    the accelerometer's output a_y (m/s^2, before its ADC; None without one). `force` (N) is
    the external force on the moving mass over the next period (the cutting force dF)."""

    BLOCK = 4096                                  # noise rows drawn at once (numpy)

    def __init__(self, axis: AxisConfig, period: float, rng: random.Random, position: float = 0.0):
        super().__init__(axis, rng)
        plant = axis.plant
        model = continuous_model(axis)
        a, n = model.a, model.a.shape[0]
        self._sensor_index, self._accelerometer_index = model.sensor, model.accelerometer
        phi, gamma_new = held_input(a, model.b_u, period - plant.loop_delay)
        _, gamma_old = held_input(a, model.b_u, plant.loop_delay)
        full, gamma_f = held_input(a, model.b_f, period)
        # one matrix, one product per step: state' = M [state, u_{k-1}, u_k, F] + the period's noise
        self._n = n
        self._m = np.hstack([full, phi @ gamma_old, gamma_new, gamma_f])
        self._noise_factor = _noise_factor(a, model.b_w, period) if model.b_w.any() else None
        self._noise = np.random.default_rng(rng.getrandbits(64))     # seeded from the plant's stream
        self._rows, self._row = np.zeros((0, n)), 0
        self.force = 0.0
        self._v = np.zeros(n + 3)                  # at rest at `position`, the flexure held by the coil
        self._v[[0, 2]] = position
        self._v[4] = plant.flexure.stiffness * position / axis.drive.force_constant
        if self._sensor_index is not None:
            self._v[self._sensor_index] = position
        self._v[n] = self._v[4] / axis.drive.amplifier_gain     # the command holding it
        self._state, self._next = self._v[:n], np.empty(n)      # a view of the state in v; the product's buffer

    @property
    def position(self) -> float:
        return float(self._v[0])

    @property
    def velocity(self) -> float:
        return float(self._v[1])

    @property
    def sensed(self) -> float:
        return float(self._v[0 if self._sensor_index is None else self._sensor_index])

    @property
    def acceleration_sensed(self) -> float | None:
        return None if self._accelerometer_index is None else float(self._v[self._accelerometer_index])

    def step(self, u: float) -> float:
        applied = self.apply(u)
        v, n = self._v, self._n
        v[n + 1] = applied
        v[n + 2] = self.force
        np.dot(self._m, v, out=self._next)
        if self._noise_factor is not None:
            if self._row == len(self._rows):
                self._rows = self._noise.standard_normal((self.BLOCK, n)) @ self._noise_factor.T
                self._row = 0
            np.add(self._next, self._rows[self._row], out=self._state)
            self._row += 1
        else:
            self._state[:] = self._next
        v[n] = applied
        return applied


class Accelerometer:
    """The accelerometer's ADC channel (AccelerometerConfig): volts = sensitivity a_y + noise,
    clipped to +-range, quantized; the reading in m/s^2 (volts / sensitivity)."""

    def __init__(self, axis: AxisConfig, rng: random.Random):
        config = axis.plant.accelerometer
        self.sensitivity, self.range = config.sensitivity, config.range
        self.resolution, self.noise, self.rng = config.resolution, config.sample_noise, rng

    def measure(self, sensed: float) -> float:
        volts = self.sensitivity * sensed + (self.rng.gauss(0.0, self.noise) if self.noise > 0.0 else 0.0)
        return quantize(min(self.range, max(-self.range, volts)), self.resolution) / self.sensitivity
