"""A voice-coil flexure stage (Ding's fast tool servo, seed 003_edeaa855566124b7) as one
linear time-invariant system, discretized exactly per control period:

    u  -> current loop H_I(s) = g w_I^2 / (s^2 + 2 zeta w_I s + w_I^2)     (Eq. 5-9), A
    F   = K_T (I + dI)                                                      (Eq. 5-10), N
    m12 x1'' = F - k2 x1 - c2 x1' - k4 (x1 - x4) - c4 (x1' - x4')           (Eqs. 5-4..5-7, k1 rigid)
    m4  x4'' =      k4 (x1 - x4) + c4 (x1' - x4')
    y   = H_capa(s) (x1 + n_s)                                              (Eq. 5-8), sensor output

with the current noise dI the output of its shaping filter (Eq. 6-7 form, `current_noise`)
and n_s the sensor's electronics noise (band-limited by the sensor itself, Eq. 6-6), each
driven by seeded white noise held over the period (variance density^2 f_s / 2 per sample:
one-sided PSD density^2 up to the Nyquist frequency). The ADC's white floor is the sensor's
per-sample noise (``plant.sensor_noise``, hw_sim/plant.py :class:`Sensor`).

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
from scipy import signal
from scipy.linalg import expm

from hw_sim.plant import _Actuator
from machine_ctrl.model.config import AxisConfig, NoiseConfig


def noise_filter(noise: NoiseConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """State space (A, B, C, D) of W(s) = density (s + corner)/s peak(s) (module doc; the
    corner term only when corner > 0)."""
    num, den = np.array([noise.density]), np.array([1.0])
    if noise.corner > 0.0:
        num, den = np.polymul(num, [1.0, noise.corner]), np.polymul(den, [1.0, 0.0])
    if noise.peak is not None:
        w, p = noise.peak.omega, noise.peak
        num = np.polymul(num, [1.0, 2.0 * p.zeta_num * w, w * w])
        den = np.polymul(den, [1.0, 2.0 * p.zeta_den * w, w * w])
    if len(den) == 1:
        return np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[noise.density]])
    return tuple(np.atleast_2d(m) for m in signal.tf2ss(num, den))


def _held_input(a: np.ndarray, b: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """(e^{A t}, integral_0^t e^{A s} ds B): a zero-order-held input over t."""
    n, m = a.shape[0], b.shape[1]
    augmented = np.zeros((n + m, n + m))
    augmented[:n, :n], augmented[:n, n:] = a, b
    d = expm(augmented * t)
    return d[:n, :n], d[:n, n:]


def continuous_model(axis: AxisConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, int | None]:
    """(A, B_u, B_w, sensor index) of the module doc's system: states [x1, v1, x4, v4, i, di],
    then the current-noise filter's, then the sensor's [y, y'] (index of y, or None without a
    sensor low-pass); inputs u (DAC volts) and w = [current noise, sensor noise] (unit white)."""
    drive, plant = axis.drive, axis.plant
    flex, loop = plant.flexure, plant.current_loop
    m12, c2, k2 = drive.mass, drive.damping, flex.stiffness
    m4, k4, c4 = flex.secondary_mass, flex.secondary_stiffness, flex.secondary_damping
    kt, wi, zi = drive.force_constant, loop.omega, loop.zeta
    current = None if plant.current_noise is None else noise_filter(plant.current_noise)
    n_cur = 0 if current is None else current[0].shape[0]
    sensor = plant.sensor_bandwidth
    n = 6 + n_cur + (0 if sensor is None else 2)
    a, b_u, b_w = np.zeros((n, n)), np.zeros((n, 1)), np.zeros((n, 2))
    a[0, 1] = 1.0                              # mechanics, Eqs. (5-4)..(5-7) with k1 rigid
    a[1, :6] = [-(k2 + k4) / m12, -(c2 + c4) / m12, k4 / m12, c4 / m12, kt / m12, 0.0]
    a[2, 3] = 1.0
    a[3, :4] = [k4 / m4, c4 / m4, -k4 / m4, -c4 / m4]
    a[4, 5] = 1.0                              # current loop, Eq. (5-9)
    a[5, 4:6] = [-wi * wi, -2.0 * zi * wi]
    b_u[5, 0] = drive.amplifier_gain * wi * wi
    if current is not None:                    # dI = C_i z_i + D_i w0 enters as K_T dI / m12
        fa, fb, fc, fd = current
        a[6:6 + n_cur, 6:6 + n_cur] = fa
        b_w[6:6 + n_cur, 0] = fb[:, 0]
        a[1, 6:6 + n_cur] = kt / m12 * fc[0]
        b_w[1, 0] = kt / m12 * fd[0, 0]
    if sensor is None:
        return a, b_u, b_w, None
    j, wc, zc = 6 + n_cur, sensor.omega, sensor.zeta      # y'' = wc^2 (x1 + n_s - y) - 2 zeta wc y'
    a[j, j + 1] = 1.0
    a[j + 1, [0, j, j + 1]] = [wc * wc, -wc * wc, -2.0 * zc * wc]
    b_w[j + 1, 1] = wc * wc                    # n_s, white (config check)
    return a, b_u, b_w, j


class FlexureAxis(_Actuator):
    """The stage of the module doc; `position` is the true tool position x1, `sensed` the
    sensor's output y (before its per-sample noise and quantization)."""

    def __init__(self, axis: AxisConfig, period: float, rng: random.Random, position: float = 0.0):
        super().__init__(axis, rng)
        plant = axis.plant
        a, b_u, b_w, self._sensor_index = continuous_model(axis)
        delay, n = plant.loop_delay, len(a)
        phi, gamma_new = _held_input(a, b_u, period - delay)
        _, gamma_old = _held_input(a, b_u, delay)
        full, gamma_w = _held_input(a, b_w, period)
        # one matrix, one product per step: state' = M [state, u_{k-1}, u_k, w0, w1]
        self._n = n
        self._m = np.hstack([full, phi @ gamma_old, gamma_new, gamma_w])
        densities = [0.0 if s is None else s.density for s in (plant.current_noise, plant.sensor_noise_density)]
        self._sigma = [d * math.sqrt(0.5 / period) for d in densities]
        self._v = np.zeros(n + 4)                  # at rest at `position`, the flexure held by the coil
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

    def step(self, u: float) -> float:
        applied = self.apply(u)
        v, n, (s0, s1) = self._v, self._n, self._sigma
        v[n + 1] = applied
        v[n + 2] = self.rng.gauss(0.0, s0) if s0 > 0.0 else 0.0
        v[n + 3] = self.rng.gauss(0.0, s1) if s1 > 0.0 else 0.0
        v[:n] = self._m @ v
        v[n] = applied
        return applied
