"""Lead-lag + integrator + notch position control of the rotary table (Yuen thesis
section 4.3, Eqs. 4.73-4.76, Table 4.4):

    C(s) = K_f (1 + alpha T s)/(1 + T s) * (1 + K_i/s) * N_a(s) N_b(s)

acting on the position error, output in the table's command unit (N or N*m).

Discretization: each section separately by the bilinear (Tustin) transform with frequency
pre-warping — the lead-lag at its centre frequency 1/(T sqrt(alpha)) (the designed
crossover omega_m, where its phase lead must survive), each notch at its own omega (so the
notch stays on the resonance), the integrator without pre-warping (its corner is far below
Nyquist). At 10 kHz the crossover's phase is then exact and the gain error < 0.1 %.
"""
from __future__ import annotations

import math

from scipy import signal

from machine_ctrl.model.config import LeadLagGains


class Biquad:
    """y/x = (b0 + b1 z^-1 + b2 z^-2) / (1 + a1 z^-1 + a2 z^-2), transposed direct form II."""

    def __init__(self, b, a):
        b = list(b) + [0.0] * (3 - len(b))
        a = list(a) + [0.0] * (3 - len(a))
        self.b0, self.b1, self.b2 = (bi / a[0] for bi in b)
        self.a1, self.a2 = a[1] / a[0], a[2] / a[0]
        self.s1 = self.s2 = 0.0

    def update(self, x: float) -> float:
        y = self.b0 * x + self.s1
        self.s1 = self.b1 * x - self.a1 * y + self.s2
        self.s2 = self.b2 * x - self.a2 * y
        return y


def tustin(num, den, period: float, prewarp: float | None = None) -> Biquad:
    """Bilinear transform of num(s)/den(s) (order <= 2), pre-warped at `prewarp` rad/s."""
    fs = 1.0 / period
    if prewarp is not None:
        fs = prewarp / (2.0 * math.tan(prewarp * period / 2.0))
    b, a = signal.bilinear(num, den, fs)
    return Biquad(b, a)


class LeadLagController:
    def __init__(self, gains: LeadLagGains, period: float):
        k, alpha, t = gains.gain, gains.alpha, gains.time_constant
        sections = [tustin([k * alpha * t, k], [t, 1.0], period, prewarp=1.0 / (t * math.sqrt(alpha)))]
        if gains.integral > 0.0:
            sections.append(tustin([1.0, gains.integral], [1.0, 0.0], period))
        for notch in gains.notches:
            w = notch.omega
            sections.append(tustin([1.0, 2.0 * notch.zeta_num * w, w * w],
                                   [1.0, 2.0 * notch.zeta_den * w, w * w], period, prewarp=w))
        self.sections = sections

    def update(self, x_r: float, v_r: float, a_r: float, x: float, v: float) -> float:
        y = x_r - x
        for section in self.sections:
            y = section.update(y)
        return y
