"""Closed-form inverse kinematics of the tilting-rotary-table 5-axis machine of Sencer et al.
(seed 001_e18aed69c6dd27eb.txt, Eqs. 3-7), axes q = [x, y, z, theta_a, theta_c] (Eq. 2).

Forward (Eq. 7, reproduced by config/machines/trt_5axis.urdf through :class:`Kinematics`):
    P = A(theta)^T [x y z]^T + N(theta) [d4 a2]^T,   O = [ca sc, ca cc, -sa]   (Eq. 4)
Inverse:
    theta_a = -asin(O_k),  theta_c = atan2(O_i, O_j)                               (Eq. 3)
    [x y z]^T = A(theta) P + [0, sa d4, ca d4 + a2]^T                             (Eq. 6)
with A = [[-cc, sc, 0], [-ca sc, -ca cc, sa], [sa sc, sa cc, ca]].

Erratum: Eq. (6) prints the a2 coefficient of the z row as -1; the exact inverse of Eq. (7)
is +1 (A N [d4 a2]^T = -[0, sa d4, ca d4 + a2]^T). We keep Eq. (7) and correct Eq. (6).
Eq. (3)'s condition "O_i = O_j != 0" means "not both zero": at |theta_a| = pi/2 the c axis
is undetermined and the caller's c_hint is kept.

d4 and a2 are not parameters here: they are read off the machine's own kinematics (one
definition of the machine), from Eq. (7) at theta_a = pi/2: P = [0, -a2, -d4].
"""
from __future__ import annotations

import math

import numpy as np

from machine_ctrl.model.kinematics import Kinematics

AXES = ('x', 'y', 'z', 'a', 'c')


class TrtInverseKinematics:
    def __init__(self, d4: float, a2: float):
        self.d4, self.a2 = d4, a2

    @classmethod
    def from_kinematics(cls, kinematics: Kinematics) -> TrtInverseKinematics:
        if kinematics.axis_names != AXES:
            raise ValueError(f'not a TRT machine: axes {kinematics.axis_names}, expected {AXES}')
        p, _ = kinematics.forward([0.0, 0.0, 0.0, math.pi / 2, 0.0])
        return cls(d4=-p[2], a2=-p[1])

    def solve(self, p, o, c_hint: float = 0.0) -> np.ndarray:
        """Axis positions for tool tip p (m) and unit tool axis o, both in the workpiece frame.
        theta_c is the solution nearest to c_hint (the c axis is continuous)."""
        oi, oj, ok = o
        a = -math.asin(min(1.0, max(-1.0, ok)))
        c = math.atan2(oi, oj) if math.hypot(oi, oj) > 1e-12 else c_hint
        c += 2 * math.pi * round((c_hint - c) / (2 * math.pi))
        sa, ca, sc, cc = math.sin(a), math.cos(a), math.sin(c), math.cos(c)
        rotation = np.array([[-cc, sc, 0.0], [-ca * sc, -ca * cc, sa], [sa * sc, sa * cc, ca]])
        xyz = rotation @ np.asarray(p, float) + np.array([0.0, sa * self.d4, ca * self.d4 + self.a2])
        return np.array([*xyz, a, c])
