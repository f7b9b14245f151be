"""A voice-coil flexure stage (Ding's fast tool servo, seed 003_edeaa855566124b7) as one
linear time-invariant system, discretized exactly per control period: the model of
machine_ctrl/model/flexure_model.py (flexure, current loop, sensor low-pass, current and
sensor noise) with each noise driven by seeded white noise held over the period (variance
density^2 f_s / 2 per sample: one-sided PSD density^2 up to the Nyquist frequency). The
ADC's white floor is the sensor's per-sample noise (``plant.sensor_noise``,
hw_sim/plant.py :class:`Sensor`).

Loop delay (section 4.4.4, DAC -> ADC): the command computed from the sample at t_k acts from
t_k + loop_delay; until then the previous command holds. Both pieces are integrated exactly
(matrix exponentials of the augmented system), so the only approximation is the held noise
(its sinc^2 roll-off is 0.4 % at 8 kHz for a 199.6 kHz period).

Not simulated yet (issue [3/8]): the ground vibration (Eq. 6-8; 1.4e-4 nm of the 0.20 nm
real error at 468 Hz in machine_ctrl/experiments/fts_budget.py), the accelerometer and the
cutting force.
"""
from __future__ import annotations

import math
import random

import numpy as np
from scipy.linalg import expm

from hw_sim.plant import _Actuator, quantize
from machine_ctrl.model.config import AxisConfig
from machine_ctrl.model.flexure_model import continuous_model


def _held_input(a: np.ndarray, b: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """(e^{A t}, integral_0^t e^{A s} ds B): a zero-order-held input over t."""
    n, m = a.shape[0], b.shape[1]
    augmented = np.zeros((n + m, n + m))
    augmented[:n, :n], augmented[:n, n:] = a, b
    d = expm(augmented * t)
    return d[:n, :n], d[:n, n:]


class FlexureAxis(_Actuator):
    """The stage of the module doc; `position` is the true tool position x1, `sensed` the
    sensor's output y (before its per-sample noise and quantization), `acceleration_sensed`
    the accelerometer's output a_y (m/s^2, before its ADC; None without one). `force` (N) is
    the external force on the moving mass over the next period (the cutting force dF)."""

    def __init__(self, axis: AxisConfig, period: float, rng: random.Random, position: float = 0.0):
        super().__init__(axis, rng)
        plant = axis.plant
        model = continuous_model(axis)
        a, n = model.a, model.a.shape[0]
        self._sensor_index, self._accelerometer_index = model.sensor, model.accelerometer
        phi, gamma_new = _held_input(a, model.b_u, period - plant.loop_delay)
        _, gamma_old = _held_input(a, model.b_u, plant.loop_delay)
        full, gamma_w = _held_input(a, np.hstack([model.b_w, model.b_f]), period)
        # one matrix, one product per step: state' = M [state, u_{k-1}, u_k, w0, w1, w2, F]
        self._n = n
        self._m = np.hstack([full, phi @ gamma_old, gamma_new, gamma_w])
        accel = plant.accelerometer
        noises = (plant.current_noise, plant.sensor_noise_density, None if accel is None else accel.noise)
        # (slot of w_j in v, sigma), drawn in this order; an absent noise's slot stays 0
        self._noises = [(n + 2 + j, s.density * math.sqrt(0.5 / period)) for j, s in enumerate(noises) if s is not None]
        self.force = 0.0
        self._v = np.zeros(n + 6)                  # at rest at `position`, the flexure held by the coil
        self._v[[0, 2]] = position
        self._v[4] = plant.flexure.stiffness * position / axis.drive.force_constant
        if self._sensor_index is not None:
            self._v[self._sensor_index] = position
        self._v[n] = self._v[4] / axis.drive.amplifier_gain     # the command holding it

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
        gauss = self.rng.gauss
        for slot, sigma in self._noises:
            v[slot] = gauss(0.0, sigma)
        v[n + 5] = self.force
        v[:n] = self._m @ v
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
