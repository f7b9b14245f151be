"""LuGre friction (Yuen thesis section 4.2.4, Eqs. 4.58-4.67).

Two users, one model:

* the plant (hw_sim) integrates the bristle deflection eps with the asymmetric Stribeck
  curve of thesis Eq. (4.41) (Table 4.2) as g(v), the friction a real axis shows;
* the controller's feed-forward (Eq. 4.66) runs the same equations with the symmetric,
  tuned g(v) of Table 4.3, integrated by forward Euler exactly as Eq. (4.67) prints it.

g(v) as printed in Eq. (4.59), F_c + F_s e^{+v/Omega_s}, diverges; we use the usual
F_c + (F_s - F_c) e^{-|v|/Omega_s} (seed-notes.md), which is Eq. (4.41) with
Omega_1 = Omega_2 = Omega_s. sigma_2 is undefined in the thesis and taken as 0 (the viscous
term b v is part of the drive model, not of the bristles).

Scalar Python on purpose: per-step code runs on floats (see README "Simulation").
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from machine_ctrl.control.law import Parameter
from machine_ctrl.model.config import AxisConfig, LuGreFeedforwardGains


@dataclass(frozen=True)
class StribeckCurve:
    """g(v) = S e^{-|v|/W1} + C (1 - e^{-|v|/W2}), parameters by direction (Eq. 4.41)."""
    static: tuple[float, float]      # (positive, negative) magnitudes, N
    coulomb: tuple[float, float]
    omega1: tuple[float, float]      # m/s
    omega2: tuple[float, float]

    @classmethod
    def symmetric(cls, coulomb: float, static: float, stribeck_velocity: float) -> StribeckCurve:
        both = (stribeck_velocity, stribeck_velocity)
        return cls((static, static), (coulomb, coulomb), both, both)

    def __call__(self, v: float) -> float:
        i = 0 if v >= 0.0 else 1
        speed = abs(v)
        return (self.static[i] * math.exp(-speed / self.omega1[i])
                + self.coulomb[i] * (1.0 - math.exp(-speed / self.omega2[i])))


def bristle_rate(v: float, eps: float, sigma0: float, g: float) -> float:
    """d eps/dt, Eq. (4.58)."""
    return v - sigma0 * abs(v) * eps / g


class LuGreFeedforward:
    """u_ff = (sigma0 eps + sigma1 d eps/dt) / (K_a K_t), Eqs. (4.66)-(4.67), driven by the
    reference velocity (feed-forward acts before the error occurs, thesis section 4.2.4).
    The servo adds it to the laws registered with friction feed-forward
    (machine_ctrl/control/registry.py); its gains: ``control.lugre_feedforward``."""

    parameters = (
        Parameter('sigma0', 'N/m', 'sigma_0, bristle stiffness, Eq. (4.58)'),
        Parameter('sigma1', 'N*s/m', 'sigma_1, bristle damping, Eq. (4.66)'),
        Parameter('coulomb', 'N', 'F_c, Coulomb friction of g(v)'),
        Parameter('static', 'N', 'F_s, static friction of g(v)'),
        Parameter('stribeck_velocity', 'm/s', 'Omega_s, Stribeck velocity of g(v)'),
    )

    @classmethod
    def from_axis(cls, gains: LuGreFeedforwardGains, axis: AxisConfig, period: float) -> LuGreFeedforward:
        curve = StribeckCurve.symmetric(gains.coulomb, gains.static, gains.stribeck_velocity)
        return cls(curve, gains.sigma0, gains.sigma1, axis.drive.gain, period)

    def __init__(self, curve: StribeckCurve, sigma0: float, sigma1: float, gain: float, period: float):
        self.curve, self.sigma0, self.sigma1 = curve, sigma0, sigma1
        self.gain, self.period = gain, period
        self.reset()

    def reset(self) -> None:
        self.eps = 0.0

    def step(self, v: float) -> float:
        rate = bristle_rate(v, self.eps, self.sigma0, self.curve(v))
        self.eps += rate * self.period
        return (self.sigma0 * self.eps + self.sigma1 * rate) / self.gain
