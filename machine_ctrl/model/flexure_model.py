"""The linear model of a voice-coil flexure axis (Ding's fast tool servo, seed
003_edeaa855566124b7, Ch. 5) built from its machine config: the machine model that the
simulated plant (hw_sim/flexure.py, the truth) and model-based laws (the H2 design of
machine_ctrl/control/h2.py, the controller's belief) both start from.

    u  -> current loop H_I(s) = g w_I^2 / (s^2 + 2 zeta w_I s + w_I^2)     (Eq. 5-9), A
    F   = K_T (I + dI)                                                      (Eq. 5-10), N
    m12 x1'' = F - k2 x1 - c2 x1' - k4 (x1 - x4) - c4 (x1' - x4')           (Eqs. 5-4..5-7, k1 rigid)
    m4  x4'' =      k4 (x1 - x4) + c4 (x1' - x4')
    y   = H_capa(s) (x1 + n_s)                                              (Eq. 5-8), sensor output

with the current noise dI the output of its shaping filter (Eq. 6-7 form, `current_noise`)
and n_s the sensor's electronics noise (band-limited by the sensor itself, Eq. 6-6), each
the response to unit white noise.
"""
from __future__ import annotations

import numpy as np
from scipy import signal

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
