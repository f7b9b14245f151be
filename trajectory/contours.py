"""Test contours of the Yuen thesis section 6.3 as axis references for two axes: the
circle of Table 6.1 and the square of Table 6.2, at a constant tangential feed with smooth
(quintic, acceleration-continuous) starts and stops: the servo references of the contour
experiments and the reference node.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from machine_ctrl.model.config import MachineConfig
from machine_ctrl.model.reference import Reference


def quintic_ramp(tau, feed: float, ramp_time: float):
    """s, ds/dt, d2s/dt2 of a feed ramp F (10 tau^3 - 15 tau^4 + 6 tau^5), tau = t / ramp_time."""
    s = feed * ramp_time * (2.5 * tau**4 - 3.0 * tau**5 + tau**6)
    v = feed * (10 * tau**3 - 15 * tau**4 + 6 * tau**5)
    a = feed / ramp_time * (30 * tau**2 - 60 * tau**3 + 30 * tau**4)
    return s, v, a


def rest_to_rest(length: float, feed: float, ramp_time: float, period: float, ramp=quintic_ramp):
    """Arc length s, ds/dt, d2s/dt2 sampled at `period`: a feed ramp up (`ramp`, covering
    feed * ramp_time / 2 like every symmetric ramp), a cruise at `feed`, and the mirror
    image of the ramp down."""
    ramp_length = feed * ramp_time / 2.0
    if length < 2.0 * ramp_length:
        raise ValueError(f'segment of {length:g} m is shorter than its two ramps ({2 * ramp_length:g} m)')
    duration = ramp_time * 2.0 + (length - 2.0 * ramp_length) / feed
    t = np.arange(int(math.ceil(duration / period)) + 1) * period
    t = np.minimum(t, duration)
    up = np.clip(t / ramp_time, 0.0, 1.0)
    down = np.clip((duration - t) / ramp_time, 0.0, 1.0)
    s_up, v_up, a_up = ramp(up, feed, ramp_time)
    s_down, v_down, a_down = ramp(down, feed, ramp_time)
    cruise = np.clip(t - ramp_time, 0.0, duration - 2.0 * ramp_time)
    in_down = t > duration - ramp_time
    s = np.where(in_down, length - s_down, s_up + feed * cruise)
    v = np.where(in_down, v_down, np.where(t < ramp_time, v_up, feed))
    a = np.where(in_down, -a_down, np.where(t < ramp_time, a_up, 0.0))
    return s, v, a


@dataclass(frozen=True)
class Contour:
    """The ideal x-y path of a reference, for contour errors."""
    kind: str                      # 'circle' or 'polygon'
    center: tuple[float, float] = (0.0, 0.0)
    radius: float = 0.0
    vertices: tuple[tuple[float, float], ...] = ()

    def errors(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Distance from each actual point to the ideal path."""
        if self.kind == 'circle':
            return np.abs(np.hypot(x - self.center[0], y - self.center[1]) - self.radius)
        points = np.column_stack((x, y))
        best = np.full(len(points), np.inf)
        corners = np.array(self.vertices + self.vertices[:1])
        for p0, p1 in zip(corners[:-1], corners[1:]):
            d = p1 - p0
            u = np.clip(((points - p0) @ d) / (d @ d), 0.0, 1.0)
            best = np.minimum(best, np.linalg.norm(points - (p0 + u[:, None] * d), axis=1))
        return best


# assumed: the thesis does not say how its contours start and stop; quintic feed ramps of
# 0.2 s (peak tangential acceleration 0.09 m/s^2 at 10 mm/s) and 0.1 s of rest before and
# after, so start-up and settling are inside the statistics as on a real machine.
RAMP_TIME = 0.2     # s
DWELL = 0.1         # s


def _two_axis_reference(machine: MachineConfig, axes, xy, vxy, axy, dwell: float) -> Reference:
    period = machine.control_period
    pad = int(round(dwell / period))
    n = len(xy) + 2 * pad
    pos = np.tile(np.asarray(machine.home, float), (n, 1))
    vel, acc = np.zeros_like(pos), np.zeros_like(pos)
    for column, axis in enumerate(axes):
        i = machine.axis_names.index(axis)
        pos[:pad, i] = xy[0, column]
        pos[pad:pad + len(xy), i] = xy[:, column]
        pos[pad + len(xy):, i] = xy[-1, column]
        vel[pad:pad + len(xy), i] = vxy[:, column]
        acc[pad:pad + len(xy), i] = axy[:, column]
    return Reference(machine.axis_names, period, pos, vel, acc)


def circle(machine: MachineConfig, radius=0.030, feed=0.010, start_angle=-math.pi / 4,
           ramp_time=RAMP_TIME, dwell=DWELL, axes=('x_c', 'y_c')) -> tuple[Reference, Contour]:
    """One revolution about the origin of `axes` (thesis Table 6.1 / Fig. 6.13: R = 30 mm at
    600 mm/min; seed-notes.md: one revolution takes 18.85 s).
    Starting at -45 deg puts all four axis reversals in the middle of the run."""
    s, v, a = rest_to_rest(2.0 * math.pi * radius, feed, ramp_time, machine.control_period)
    theta = start_angle + s / radius
    w, dw = v / radius, a / radius
    c, sn = np.cos(theta), np.sin(theta)
    xy = radius * np.column_stack((c, sn))
    vxy = radius * w[:, None] * np.column_stack((-sn, c))
    axy = radius * (dw[:, None] * np.column_stack((-sn, c)) - (w * w)[:, None] * np.column_stack((c, sn)))
    return _two_axis_reference(machine, axes, xy, vxy, axy, dwell), Contour('circle', radius=radius)


def square(machine: MachineConfig, side=0.020, feed=0.010, ramp_time=RAMP_TIME, dwell=DWELL,
           axes=('x_c', 'y_c')) -> tuple[Reference, Contour]:
    """Square about the origin, counter-clockwise from the lower-left corner, stopping at
    each corner. assumed: side 20 mm (thesis Table 6.2 does not state it)."""
    h = side / 2.0
    corners = [(-h, -h), (h, -h), (h, h), (-h, h)]
    s, v, a = rest_to_rest(side, feed, ramp_time, machine.control_period)
    parts = [], [], []
    for p0, p1 in zip(corners, corners[1:] + corners[:1]):
        direction = (np.array(p1) - np.array(p0)) / side
        parts[0].append(np.array(p0) + s[:, None] * direction)
        parts[1].append(v[:, None] * direction)
        parts[2].append(a[:, None] * direction)
    xy, vxy, axy = (np.concatenate(p) for p in parts)
    return (_two_axis_reference(machine, axes, xy, vxy, axy, dwell),
            Contour('polygon', vertices=tuple(corners)))


def contour_reference(machine: MachineConfig, contour: str) -> Reference:
    """The reference of a test contour by name: circle, square, or hold (stay at home)."""
    if contour == 'hold':
        return Reference.hold(machine.axis_names, machine.control_period, machine.home, 1)
    if contour not in ('circle', 'square'):
        raise ValueError(f'contour must be circle, square or hold, got {contour!r}')
    return globals()[contour](machine)[0]
