"""The linear model of a voice-coil flexure axis (Ding's fast tool servo, seed
003_edeaa855566124b7, Ch. 5) built from its machine config: the machine model that the
simulated plant (hw_sim/flexure.py, from the plant's mechanics: the truth) and model-based laws
(the H2 design of machine_ctrl/control/h2.py, from the drive's: the controllers' belief) both
start from.

    u  -> current loop H_I(s) = g w_I^2 / (s^2 + 2 zeta w_I s + w_I^2)     (Eq. 5-9), A
    F   = K_T (I + dI)                                                      (Eq. 5-10), N
    m12 x1'' = F - k2 (x1 - x_g) - c2 (x1' - x_g') - k4 (x1 - x4) - c4 (x1' - x4')
                                                                           (Eqs. 5-4..5-7, k1 rigid)
    m4  x4'' =      k4 (x1 - x4) + c4 (x1' - x4')
    y   = H_capa(s) (x1 + n_s)                                              (Eq. 5-8), sensor output
    a_y = H_acc(s) (x1'' + n_a)                          (Fig. 7-6, Table 7-2), accelerometer output

with the current noise dI the output of its shaping filter (Eq. 6-7 form, `current_noise`),
n_s the sensor's electronics noise (band-limited by the sensor itself, Eq. 6-6) and n_a the
accelerometer's (through its conditioning low-pass, section 7.5.1), each the response to
unit white noise; a force F on m12 (the cutting force dF of Eq. 7-7) enters as F / m12.
The ground vibration x_g moves the flexure's root (m3 of Eqs. 5-4..5-7 is the ground, as in
machine_ctrl/experiments/fts_budget.py's G_g = (c2 s + k2) G): x_g is its filter's output
(Eq. 6-8 form, with the config's roll-off, so x_g' is finite). assumed: the sensor reads x1
as the budget has it (its mount's own motion with the ground is not modelled apart; the thesis
does not say where the capacitive sensor's target and probe sit relative to the ground path).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from machine_ctrl.model.config import AxisConfig, NoiseConfig


def held_input(a: np.ndarray, b: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """(e^{A t}, integral_0^t e^{A s} ds B): the exact effect of an input held over t."""
    n, m = a.shape[0], b.shape[1]
    augmented = np.zeros((n + m, n + m))
    augmented[:n, :n], augmented[:n, n:] = a, b
    d = expm(augmented * t)
    return d[:n, :n], d[:n, n:]


def noise_filter(noise: NoiseConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """State space (A, B, C, D) of W(s) = density (s + corner)/s peak(s) r/(s + r) (module doc;
    the corner term only when corner > 0, the roll-off r only when rolloff > 0)."""
    num, den = np.array([noise.density]), np.array([1.0])
    if noise.corner > 0.0:
        num, den = np.polymul(num, [1.0, noise.corner]), np.polymul(den, [1.0, 0.0])
    if noise.peak is not None:
        w, p = noise.peak.omega, noise.peak
        num = np.polymul(num, [1.0, 2.0 * p.zeta_num * w, w * w])
        den = np.polymul(den, [1.0, 2.0 * p.zeta_den * w, w * w])
    if noise.rolloff > 0.0:
        num, den = num * noise.rolloff, np.polymul(den, [1.0, noise.rolloff])
    if len(den) == 1:
        return np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[noise.density]])
    from scipy import signal      # here: hw_sim of a machine without flexures need not import it (~0.8 s)
    return tuple(np.atleast_2d(m) for m in signal.tf2ss(num, den))


@dataclass(frozen=True)
class FlexureModel:
    """x' = a x + b_u u + b_w w + b_f F: u the DAC volts, w white noise of one-sided PSD 1 per Hz
    [current, sensor, accelerometer, ground] (each column carries its noise's density; zeros
    where the axis has no such noise), F a force on the moving mass m12 (N; the cutting force
    dF of Eq. 7-7). States [x1, v1, x4, v4, i, di], the current-noise filter's, the sensor's
    [y, y'], the accelerometer noise filter's, the accelerometer's [a_y, a_y'], the ground
    filter's (the last five groups only when configured); `sensor` and `accelerometer` index y
    and a_y (None without them); `current_noise` the current-noise filter's states; `core` the
    number of states before the accelerometer's: a model-based design may keep a[:core, :core]
    (no ground: the ground states are outside it, their coupling into the mechanics dropped)."""
    a: np.ndarray
    b_u: np.ndarray
    b_w: np.ndarray
    b_f: np.ndarray
    sensor: int | None
    accelerometer: int | None
    current_noise: slice
    core: int


def _add_filter(a: np.ndarray, b_w: np.ndarray, column: int, noise: NoiseConfig | None, start: int):
    """Place W(s) of `noise` at states start.. driven by w[column]; (C, D) of its output."""
    if noise is None:
        return np.zeros(0), 0.0
    fa, fb, fc, fd = noise_filter(noise)
    n = fa.shape[0]
    a[start:start + n, start:start + n] = fa
    b_w[start:start + n, column] = fb[:, 0]
    return fc[0], fd[0, 0]


def _filter_order(noise: NoiseConfig | None) -> int:
    return 0 if noise is None else noise_filter(noise)[0].shape[0]


def continuous_model(axis: AxisConfig, belief: bool = False) -> FlexureModel:
    """The module doc's system for `axis` (a voice_coil drive with its flexure and current loop):
    the stage's mechanics (m12, c2 and the flexure) as hw_sim simulates them (the plant's: the
    truth) or, with `belief`, as the controllers know them (the drive's mass, damping and
    flexure; ValueError where the drive has no flexure). The current loop, the sensor, the delay
    and the noises are the plant's either way, K_T and the amplifier gain the drive's (shared
    by truth and belief): measured apart, as the thesis had them
    (section 5.5: the grey-box fit takes them as known)."""
    drive, plant = axis.drive, axis.plant
    body = drive if belief else plant
    if body.flexure is None:
        raise ValueError(f'axis {axis.name}: no flexure in its ' + (
            'drive (drive.flexure: the controllers\' model of the stage; `machine-ctrl identify` writes one)'
            if belief else 'plant (a voice_coil drive\'s plant.flexure)'))
    flex, loop, accel = body.flexure, plant.current_loop, plant.accelerometer
    m12, c2, k2 = body.mass, body.damping, flex.stiffness
    m4, k4, c4 = flex.secondary_mass, flex.secondary_stiffness, flex.secondary_damping
    kt, wi, zi = drive.force_constant, loop.omega, loop.zeta
    n_cur = _filter_order(plant.current_noise)
    sensor = None if plant.sensor_bandwidth is None else 6 + n_cur
    j_acc = 6 + n_cur + (0 if sensor is None else 2)            # first state of the accelerometer's noise filter
    n_acc = 0 if accel is None else _filter_order(accel.noise)
    j_ground = j_acc + (0 if accel is None else n_acc + 2)
    n = j_ground + _filter_order(plant.ground_vibration)
    a, b_u, b_w, b_f = np.zeros((n, n)), np.zeros((n, 1)), np.zeros((n, 4)), np.zeros((n, 1))
    a[0, 1] = 1.0                              # mechanics, Eqs. (5-4)..(5-7) with k1 rigid
    a[1, :6] = [-(k2 + k4) / m12, -(c2 + c4) / m12, k4 / m12, c4 / m12, kt / m12, 0.0]
    b_f[1, 0] = 1.0 / m12
    gc, _ = _add_filter(a, b_w, 3, plant.ground_vibration, j_ground)   # x_g = C_g z_g (strictly proper: roll-off)
    if len(gc):                                # (k2 x_g + c2 x_g') / m12, x_g' = C_g (A_g z_g + B_g w3)
        g = slice(j_ground, n)
        a[1, g] = (k2 * gc + c2 * gc @ a[g, g]) / m12
        b_w[1, 3] = c2 * gc @ b_w[g, 3] / m12
    a[2, 3] = 1.0
    a[3, :4] = [k4 / m4, c4 / m4, -k4 / m4, -c4 / m4]
    a[4, 5] = 1.0                              # current loop, Eq. (5-9)
    a[5, 4:6] = [-wi * wi, -2.0 * zi * wi]
    b_u[5, 0] = drive.amplifier_gain * wi * wi
    fc, fd = _add_filter(a, b_w, 0, plant.current_noise, 6)     # dI = C_i z_i + D_i w0 enters as K_T dI / m12
    a[1, 6:6 + n_cur] = kt / m12 * fc
    b_w[1, 0] = kt / m12 * fd
    if sensor is not None:                     # y'' = wc^2 (x1 + n_s - y) - 2 zeta wc y'
        wc, zc = plant.sensor_bandwidth.omega, plant.sensor_bandwidth.zeta
        a[sensor, sensor + 1] = 1.0
        a[sensor + 1, [0, sensor, sensor + 1]] = [wc * wc, -wc * wc, -2.0 * zc * wc]
        density = 0.0 if plant.sensor_noise_density is None else plant.sensor_noise_density.density
        b_w[sensor + 1, 1] = wc * wc * density  # n_s, white (config check)
    if accel is None:
        return FlexureModel(a, b_u, b_w, b_f, sensor, None, slice(6, 6 + n_cur), j_acc)
    # a_y'' = wa^2 (x1'' + n_a - a_y) - 2 zeta wa a_y', x1'' the mechanics' row 1
    na_c, na_d = _add_filter(a, b_w, 2, accel.noise, j_acc)
    k = j_acc + n_acc
    wa, za = accel.bandwidth.omega, accel.bandwidth.zeta
    a[k, k + 1] = 1.0
    a[k + 1] = wa * wa * a[1]
    a[k + 1, j_acc:k] += wa * wa * na_c
    a[k + 1, [k, k + 1]] += [-wa * wa, -2.0 * za * wa]
    b_w[k + 1] = wa * wa * b_w[1]
    b_w[k + 1, 2] += wa * wa * na_d
    b_f[k + 1, 0] = wa * wa / m12
    return FlexureModel(a, b_u, b_w, b_f, sensor, k, slice(6, 6 + n_cur), j_acc)
