"""Points per second of trajectory.redundancy.resolve on the 9-axis micromill: a closed-form
helix (R = 2 mm, pitch 0.5 mm, tool axis wobbling within 0.3 deg of vertical) of exactly
10,000 steps of Δs = 20 µm, all axes active, default settings (RK4 + Newton projection +
the three derivative outputs). Prints the figure; no timing asserts anywhere.

    .venv/bin/python bench/redundancy_rate.py [STEPS]
"""
from __future__ import annotations

import math
import sys
import time

import numpy as np

from machine_ctrl.model.config import load_machine
from machine_ctrl.model.kinematics import Kinematics
from trajectory.redundancy import RedundancySettings, resolve


class Helix:
    """P = c + (r cos t, r sin t, a t), t = s / k (unit speed); O from two small angles,
    alpha = A sin t, gamma = G cos t: O = (cos alpha sin gamma, -sin alpha, cos alpha cos gamma).
    Derivatives of O by central differences (good enough for a rate measurement). Takes an
    array s (M,) and returns (M, 3) arrays; trajectory.redundancy calls `tangents`."""

    def __init__(self, centre, length, radius=2e-3, pitch=0.5e-3, tilt=3e-3):
        self.c, self.r, self.a = np.asarray(centre, float), radius, pitch / (2 * math.pi)
        self.k = math.hypot(radius, self.a)
        self.length, self.tilt = length, tilt

    def _o(self, s):
        t = np.asarray(s, float) / self.k
        al, ga = self.tilt * np.sin(t), self.tilt * np.cos(t)
        return np.column_stack((np.cos(al) * np.sin(ga), -np.sin(al), np.cos(al) * np.cos(ga)))

    def evaluate(self, s):
        t = np.asarray(s, float) / self.k
        p = self.c + np.column_stack((self.r * np.cos(t), self.r * np.sin(t), self.a * t))
        return p, self._o(s)

    def derivatives(self, s, order):
        s = np.asarray(s, float)
        t, f = s / self.k, self.k ** -order
        c, sn = np.cos(t), np.sin(t)
        d = [(-sn, c), (-c, -sn), (sn, -c)][order - 1]
        p = np.column_stack((self.r * d[0] * f, self.r * d[1] * f,
                             np.full_like(s, self.a / self.k if order == 1 else 0.0)))
        h = 1e-5
        if order == 1:
            o = (self._o(s + h) - self._o(s - h)) / (2 * h)
        elif order == 2:
            o = (self._o(s + h) - 2 * self._o(s) + self._o(s - h)) / h**2
        else:
            o = (self._o(s + 2 * h) - 2 * self._o(s + h) + 2 * self._o(s - h) - self._o(s - 2 * h)) / (2 * h**3)
        return p, o

    def tangents(self, s):
        return [self.evaluate(s), self.derivatives(s, 1)]


def main():
    steps = int(sys.argv[1]) if len(sys.argv) > 1 else 10_000
    machine = load_machine('micromill_9axis')
    kin = Kinematics.from_config(machine)
    settings = RedundancySettings()
    tip = kin.forward(np.array(machine.home))[0]
    path = Helix(tip + np.array([-2e-3, 0.0, 0.0]), steps * settings.step)
    start = time.perf_counter()
    res = resolve(path, kin, machine, settings)
    elapsed = time.perf_counter() - start
    points = len(res.s)
    print(f'redundancy resolution, micromill_9axis, {points} points ({path.length * 1e3:.1f} mm '
          f'at Δs = {settings.step * 1e6:g} µm): {elapsed:.2f} s, {points / elapsed:.0f} points/s; '
          f'max error {res.max_position_error:.2e} m, {res.max_orientation_error:.2e} rad')


if __name__ == '__main__':
    main()
