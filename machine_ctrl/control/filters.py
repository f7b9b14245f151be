"""Discrete filter building blocks shared by the control laws: one biquad section and its
design from a continuous transfer function by the bilinear (Tustin) transform, optionally
pre-warped. Scalar Python floats (per-step code, see README "Simulation").
"""
from __future__ import annotations

import math

from scipy import signal


class Biquad:
    """y/x = (b0 + b1 z^-1 + b2 z^-2) / (1 + a1 z^-1 + a2 z^-2), transposed direct form II."""

    def __init__(self, b, a):
        b = list(b) + [0.0] * (3 - len(b))
        a = list(a) + [0.0] * (3 - len(a))
        self.b0, self.b1, self.b2 = (bi / a[0] for bi in b)
        self.a1, self.a2 = a[1] / a[0], a[2] / a[0]
        self.reset()

    def reset(self) -> None:
        """Zero state: the section's output starts from rest."""
        self.s1 = self.s2 = 0.0

    def step(self, x: float) -> float:
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
