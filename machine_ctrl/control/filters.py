"""Discrete filter building blocks shared by the control laws: one biquad section and its
design from a continuous transfer function by the bilinear (Tustin) transform, optionally
pre-warped. Scalar Python floats (per-step code, see README "Simulation").

The transform is numpy's polynomial arithmetic, not scipy.signal: a servo process would
otherwise import scipy.signal (and scipy.stats with it) for it, about 0.8 s of its start.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.polynomial import Polynomial


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
    b, a = bilinear(num, den, fs)
    return Biquad(b, a)


def bilinear(num, den, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """num(s)/den(s) with s = 2 fs (z - 1)/(z + 1): the coefficients of the numerator and
    denominator in z, highest power first, both divided by the denominator's first. The
    factor 2 fs is split between (z + 1) and (z - 1) as scipy.signal.bilinear does (the same
    arithmetic, so the same bits); unlike it, a zero leading coefficient is kept in place.
    ValueError when the denominator vanishes at s = 2 fs (no z^n term)."""
    num, den = np.atleast_1d(np.asarray(num, float)), np.atleast_1d(np.asarray(den, float))
    order = max(len(num), len(den)) - 1
    fac = np.sqrt(2.0 * fs)
    z_plus, z_minus = Polynomial((1.0, 1.0)) / fac, Polynomial((-1.0, 1.0)) * fac

    def in_z(c):
        p = sum(c_ * z_plus ** (order - q) * z_minus ** q for q, c_ in enumerate(c[::-1]))
        ascending = np.zeros(order + 1)
        ascending[:len(p.coef)] = p.coef
        return ascending[::-1]
    b, a = in_z(num), in_z(den)
    if a[0] == 0.0:
        raise ValueError('the denominator vanishes at s = 2 fs: no bilinear transform of this order')
    return b / a[0], a / a[0]
