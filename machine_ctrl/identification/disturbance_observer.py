"""The feed drive's disturbance Kalman observer (Yuen thesis section 4.2.2, Eqs. 4.23-4.40),
designed from a rigid-body model and the noise of the machine's converters. Plain numeric
functions (numpy, scipy.linalg); no ROS, no simulator.

The drive in command units (volts): x' = v, v' = p_v v + K_v (u - d), p_v = -b/m, K_v = K/m
(K = K_a K_t; Eqs. 4.23-4.26), held over the period T (Eqs. 4.27-4.29) and augmented with the
disturbance d as a random walk (Eqs. 4.30-4.32): state [x, v, d], measured [x, v]. Noise:

    R_x = dx^2 / 12            encoder quantization, Eq. (4.33)
    R_v = (dx / T)^2 / 12      its difference over one period, Eq. (4.34)
    R_u = du^2 / 12            command quantization (the PWM's 400 levels), Eq. (4.35)
    R_wd                       the disturbance's random walk, a tuning value: 1e-6, Eq. (4.36)

The gain K_obs of the filter (Eq. 4.37, with its "=" read as "+", seed-notes.md) is the
steady-state Kalman gain of the predicted covariance P (scipy.linalg.solve_discrete_are):

    P = A P A' - A P C' (C P C' + R)^-1 C P A' + W Q W',   K_obs = P C' (C P C' + R)^-1

with Q = diag(R_u, R_wd), R = diag(R_x, R_v). The thesis printed its gains (4.38)-(4.40) in mm
and V; :func:`thesis_units` converts ours (SI: m, V) to those.

The quantization steps can be read from recorded data (:func:`quantization_step`): the
smallest gap between distinct recorded values, so the noise is estimated from what the
machine gave, not copied from its data sheet.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from machine_ctrl.identification.status import FitStatus
from machine_ctrl.model.flexure_model import held_input

DISTURBANCE_WALK = 1e-6     # R_wd, V^2 per period: thesis Eq. (4.36), its tuning value


@dataclass(frozen=True)
class ObserverDesign:
    status: FitStatus
    reason: str = ''
    gain: np.ndarray | None = None      # K_obs, 3 x 2: rows x, v, d; columns x_m (m), v_m (m/s); SI
    noise: tuple[float, float, float, float] = (math.nan,) * 4    # R_x, R_v, R_u, R_wd


def disturbance_observer(mass: float, damping: float, force_gain: float, period: float, position_step: float,
                         command_step: float, disturbance_walk: float = DISTURBANCE_WALK) -> ObserverDesign:
    """K_obs (module docstring) for a drive of `mass` (kg) and `damping` (N s/m) driven by
    `force_gain` N per command unit, sampled every `period` s, with an encoder of
    `position_step` (m) and a command of `command_step` (V) resolution."""
    values = {'mass': mass, 'force_gain': force_gain, 'period': period, 'position_step': position_step,
              'command_step': command_step, 'disturbance_walk': disturbance_walk}
    bad = [f'{name} {value!r}' for name, value in values.items() if not (math.isfinite(value) and value > 0)]
    if not (math.isfinite(damping) and damping >= 0):
        bad.append(f'damping {damping!r}')
    if bad:
        return ObserverDesign(FitStatus.REFUSED, f'must be finite and > 0 (damping >= 0): {", ".join(bad)}')
    from scipy.linalg import solve_discrete_are
    p_v, k_v = -damping / mass, force_gain / mass
    a_d, b_d = held_input(np.array([[0.0, 1.0], [0.0, p_v]]), np.array([[0.0], [k_v]]), period)  # Eqs. 4.28-4.29
    a = np.block([[a_d, -b_d], [np.zeros((1, 2)), np.ones((1, 1))]])       # Eq. (4.32): u - d
    w = np.block([[b_d, np.zeros((2, 1))], [np.zeros((1, 1)), np.ones((1, 1))]])
    c = np.hstack((np.eye(2), np.zeros((2, 1))))
    r_x = position_step ** 2 / 12.0
    noise = (r_x, r_x / period ** 2, command_step ** 2 / 12.0, disturbance_walk)
    q, r = np.diag(noise[2:]), np.diag(noise[:2])
    try:
        p = solve_discrete_are(a.T, c.T, w @ q @ w.T, r)
    except (np.linalg.LinAlgError, ValueError) as exc:
        return ObserverDesign(FitStatus.REFUSED, f'no steady-state Kalman gain: {exc}')
    gain = p @ c.T @ np.linalg.inv(c @ p @ c.T + r)
    return ObserverDesign(FitStatus.OK, '', gain, noise)


def thesis_units(gain: np.ndarray) -> np.ndarray:
    """K_obs in the thesis's mm and V (Eqs. 4.38-4.40) from SI: a gain from x_m or v_m (per m)
    to x or v (m) is unit-free; to d (V) it is per mm, 1/1000 of per m."""
    return np.asarray(gain) * np.array([[1.0], [1.0], [1e-3]])


def quantization_step(values, floor: float | None = None) -> float:
    """The resolution of recorded `values`: the smallest gap between distinct values larger
    than `floor` (default 1e-9 of the largest magnitude: the rounding residue of values that
    are whole multiples of the step), or nan when there is no such gap."""
    distinct = np.unique(np.asarray(values, float))
    if floor is None:
        floor = 1e-9 * float(np.abs(distinct).max()) if distinct.size else 0.0
    gaps = np.diff(distinct)
    gaps = gaps[gaps > floor]
    return float(gaps.min()) if gaps.size else math.nan
