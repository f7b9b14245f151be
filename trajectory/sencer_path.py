"""The five-axis test path of Sencer, Altintas & Croft 2009 (seed 001_e18aed69c6dd27eb.txt,
Eq. 35, section 4) as axis references of the `trt_5axis` machine.

Eq. (35), lengths in mm, l = 0 ... 4 pi:

    P_x = 15 cos l + 5 sin l,   P_y = 15 sin l - 5 cos l,   P_z = 15 l
    a   = -asin(sin(l) / sqrt 5)
    c   = -atan(cos(l) / sqrt 5)

Typo: Eq. (35) prints c_ref = -tan(cos(l)/sqrt 5); we read it as the inverse tangent
(seed-notes.md), like a_ref's inverse sine: the tool axis of Eq. (4) then has
O_k = -sin a = sin(l)/sqrt 5 and O_i/O_j = tan c = -cos(l)/sqrt 5, both bounded, smooth and
with Eq. (3) (theta_a = -asin O_k, theta_c = atan2(O_i, O_j)) giving back exactly a and c
(test/test_trt_path.py). |dP/dl| = sqrt(15^2 + 5^2 + 15^2) mm is constant, so l is
proportional to arc length; 4 pi l gives the seed's 273.87 mm.

Feed (section 4): "maximum cruise feed of 50 mm/s and cubic acceleration/decelerations not
exceeding 1500 mm/s^2": the tangential feed rises as a cubic in time, F (3 tau^2 - 2 tau^3),
whose peak acceleration 1.5 F / T_ramp equals 1500 mm/s^2 at T_ramp = 50 ms. On our
trt_5axis that ramp would ask y for 7.2 m/s^2 at the end of the path (the a tilt swings
the 0.21 m high tool tip; y can give 10 V / 1.74 V s^2/m = 5.7 m/s^2): the ramp is
lengthened until every axis is within its acceleration and jerk limits (122 ms, 617
mm/s^2 tangential: still "not exceeding 1500 mm/s^2").

The axes follow from the inverse kinematics (Eqs. 3 and 6, with the Eq. 6 erratum of
machine_ctrl/model/trt_kinematics.py). Derivatives are exact: every quantity is carried as a
second-order jet (value, d/dl, d2/dl2), then q' = q_l l', q'' = q_ll l'^2 + q_l l''.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from machine_ctrl.model.config import MachineConfig
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.model.reference import Reference
from machine_ctrl.model.trt_kinematics import AXES, TrtInverseKinematics
from trajectory.contours import rest_to_rest

RADIUS_COS, RADIUS_SIN, PITCH = 0.015, 0.005, 0.015   # m, Eq. (35) (15, 5 and 15 mm)
L_END = 4.0 * math.pi                                   # Eq. (35)
FEED = 0.050                    # m/s, Sencer section 4 (maximum cruise feed 50 mm/s)
ACCELERATION = 1.5              # m/s^2, Sencer section 4 (not exceeding 1500 mm/s^2)
DWELL = 0.2                     # s, assumed: rest before and after, so start-up and settling are in the run


@dataclass(frozen=True)
class Jet:
    """f, df/dl, d2f/dl2 of arrays of l (second-order forward-mode differentiation)."""
    f: np.ndarray
    d1: np.ndarray
    d2: np.ndarray

    def __add__(self, other):
        other = _jet(other)
        return Jet(self.f + other.f, self.d1 + other.d1, self.d2 + other.d2)

    __radd__ = __add__

    def __neg__(self):
        return Jet(-self.f, -self.d1, -self.d2)

    def __sub__(self, other):
        return self + (-_jet(other))

    def __mul__(self, other):
        other = _jet(other)
        return Jet(self.f * other.f, self.d1 * other.f + self.f * other.d1,
                   self.d2 * other.f + 2.0 * self.d1 * other.d1 + self.f * other.d2)

    __rmul__ = __mul__


def _jet(x) -> Jet:
    return x if isinstance(x, Jet) else Jet(np.asarray(x, float), 0.0, 0.0)


def _apply(u: Jet, f, df, ddf) -> Jet:
    """g(u) by the chain rule: g' = g_u u', g'' = g_uu u'^2 + g_u u''."""
    return Jet(f(u.f), df(u.f) * u.d1, ddf(u.f) * u.d1 ** 2 + df(u.f) * u.d2)


def sin(u: Jet) -> Jet:
    return _apply(u, np.sin, np.cos, lambda x: -np.sin(x))


def cos(u: Jet) -> Jet:
    return _apply(u, np.cos, lambda x: -np.sin(x), lambda x: -np.cos(x))


def asin(u: Jet) -> Jet:
    return _apply(u, np.arcsin, lambda x: (1 - x * x) ** -0.5, lambda x: x * (1 - x * x) ** -1.5)


def atan(u: Jet) -> Jet:
    return _apply(u, np.arctan, lambda x: 1 / (1 + x * x), lambda x: -2 * x / (1 + x * x) ** 2)


def eq35(l: np.ndarray) -> tuple[list[Jet], Jet, Jet]:
    """Tool tip [P_x, P_y, P_z] (m) and rotary angles a, c (rad) of Eq. (35) as jets in l
    (c with the inverse tangent, see the module docstring)."""
    lj = Jet(np.asarray(l, float), np.ones_like(l, dtype=float), np.zeros_like(l, dtype=float))
    s, c = sin(lj), cos(lj)
    p = [RADIUS_COS * c + RADIUS_SIN * s, RADIUS_COS * s - RADIUS_SIN * c, PITCH * lj]
    return p, -asin(s * (1 / math.sqrt(5))), -atan(c * (1 / math.sqrt(5)))


def axis_jets(l: np.ndarray, d4: float, a2: float) -> list[Jet]:
    """Axes [x, y, z, a, c] along Eq. (35) through Eq. (6) (a2 coefficient +1, erratum):
    [x y z]^T = A(a, c) P + [0, sa d4, ca d4 + a2]^T."""
    p, a, c = eq35(l)
    sa, ca, sc, cc = sin(a), cos(a), sin(c), cos(c)
    x = -cc * p[0] + sc * p[1]
    y = -ca * sc * p[0] - ca * cc * p[1] + sa * p[2] + d4 * sa
    z = sa * sc * p[0] + sa * cc * p[1] + ca * p[2] + d4 * ca + a2
    return [x, y, z, a, c]


def cubic_ramp(tau, feed: float, ramp_time: float):
    """s, ds/dt, d2s/dt2 of a feed ramp F (3 tau^2 - 2 tau^3), tau = t / ramp_time (Sencer
    section 4, "cubic acceleration/decelerations"); contours.rest_to_rest adds the cruise
    and the mirror image down."""
    return (feed * ramp_time * (tau ** 3 - 0.5 * tau ** 4), feed * (3 * tau ** 2 - 2 * tau ** 3),
            feed / ramp_time * (6 * tau - 6 * tau ** 2))


def sencer_reference(machine: MachineConfig, feed: float = FEED, acceleration: float = ACCELERATION,
                     dwell: float = DWELL) -> Reference:
    """Axis references of Eq. (35) on a TRT machine: cubic feed ramps, cruise at `feed`,
    `dwell` s at rest before and after. The ramp is the seed's (peak tangential acceleration
    `acceleration`) unless an axis would exceed its acceleration or jerk limit; then it is
    lengthened until none does (:func:`ramp_for_limits`)."""
    if machine.axis_names != AXES:
        raise ValueError(f'{machine.name}: the Eq. (35) path needs axes {AXES}, not {machine.axis_names}')
    ik = TrtInverseKinematics.from_kinematics(Kinematics.from_config(machine))
    ramp_time = ramp_for_limits(machine, lambda ramp: _path(machine, ik, feed, ramp), 1.5 * feed / acceleration)
    position, velocity, acc = _path(machine, ik, feed, ramp_time)
    pad = int(round(dwell / machine.control_period))
    rest = np.zeros((pad, len(AXES)))
    return Reference(machine.axis_names, machine.control_period,
                     np.vstack((np.tile(position[0], (pad, 1)), position, np.tile(position[-1], (pad, 1)))),
                     np.vstack((rest, velocity, rest)), np.vstack((rest, acc, rest)))


def _path(machine: MachineConfig, ik: TrtInverseKinematics, feed: float, ramp_time: float):
    speed_per_l = math.sqrt(RADIUS_COS ** 2 + RADIUS_SIN ** 2 + PITCH ** 2)    # |dP/dl|, m/rad
    s, sd, sdd = rest_to_rest(speed_per_l * L_END, feed, ramp_time, machine.control_period, cubic_ramp)
    l, ld, ldd = s / speed_per_l, sd / speed_per_l, sdd / speed_per_l
    jets = axis_jets(l, ik.d4, ik.a2)
    return (np.column_stack([j.f for j in jets]), np.column_stack([j.d1 * ld for j in jets]),
            np.column_stack([j.d2 * ld ** 2 + j.d1 * ldd for j in jets]))


def limit_ratios(machine: MachineConfig, velocity: np.ndarray, acceleration: np.ndarray):
    """Largest |v|, |a| and |jerk| (finite difference of a at the control period) over each
    axis's limit: three arrays, one value per axis."""
    jerk = np.diff(acceleration, axis=0) / machine.control_period
    limits = np.array([[a.limits.velocity, a.limits.acceleration, a.limits.jerk] for a in machine.axes])
    return (np.abs(velocity).max(0) / limits[:, 0], np.abs(acceleration).max(0) / limits[:, 1],
            np.abs(jerk).max(0) / limits[:, 2])


def ramp_for_limits(machine: MachineConfig, make, ramp_time: float, iterations: int = 20) -> float:
    """Shortest tried ramp time >= `ramp_time` whose path (`make(ramp)` -> q, v, a) keeps
    every axis within its acceleration and jerk limits: ramp accelerations scale as
    1/T and jerks as 1/T^2, so T grows by the worst of ratio_a and sqrt(ratio_j) (and 2 %)."""
    for _ in range(iterations):
        _, velocity, acceleration = make(ramp_time)
        v, a, j = limit_ratios(machine, velocity, acceleration)
        if v.max() > 1.0:
            raise ValueError(f'{machine.name}: the feed exceeds the velocity limit {v.max():.2f}x '
                             'whatever the ramp (lower the feed)')
        worst = max(a.max(), math.sqrt(j.max()))
        if worst <= 1.0:
            return ramp_time
        ramp_time *= worst * 1.02
    raise ValueError(f'{machine.name}: no ramp keeps the Eq. (35) path within the acceleration and jerk '
                     'limits (the cruise itself exceeds them: lower the feed)')
