"""What an axis of the machine accepts as a position, and how a refusal says it: the stroke
of a limited axis, the range of an unlimited (continuous) rotary axis, and the amounts in
readable units. Shared by the point-to-point moves, the redundancy resolution and the
planner, so a position outside its axis is told the same way everywhere (machine axis
positions in m or rad; lengths of the tool path in m).
"""
from __future__ import annotations

import math

from machine_ctrl.model.config import AxisConfig

# Issue [3/7]: every sampled reference within 1.001 x its velocity, acceleration and jerk limit.
TOLERANCE = 1.001

_PREFIXES = ((1.0, ''), (1e-3, 'm'), (1e-6, 'µ'), (1e-9, 'n'))


def amount(value: float, unit: str) -> str:
    """|value| in `unit` ('m', 'rad', 's', ...) with the SI prefix that keeps 1-3 digits
    before the point (none above 1 unit), 3 significant digits: 0.0032 m -> '3.2 mm',
    0.091 rad -> '91 mrad', 1000 m/s -> '1000 m/s'; rounded before the prefix is chosen, so
    999.99 m/s reads '1000 m/s' and 0.99999 mm '1 mm' (not '1e+03')."""
    size = float(f'{abs(value):.3g}')
    scale, prefix = next(((scale, prefix) for scale, prefix in _PREFIXES if size >= scale), (1.0, ''))
    size /= scale
    return f'{size:.0f} {prefix}{unit}' if 1e3 <= size < 1e6 else f'{size:.3g} {prefix}{unit}'


def stroke_text(axis: AxisConfig) -> str:
    """'[-0.05, 0.05] m': the stroke of a limited axis."""
    return f'[{axis.stroke[0]:g}, {axis.stroke[1]:g}] {axis.unit}'


def stroke_excess(axis: AxisConfig, value: float) -> float:
    """How far `value` lies outside the stroke of `axis` (m or rad; 0 inside it or when
    the axis is unlimited)."""
    if axis.stroke is None:
        return 0.0
    return max(axis.stroke[0] - value, value - axis.stroke[1], 0.0)


def outside_stroke(axis: AxisConfig, value: float, verb: str = 'at', where: str = '') -> str:
    """'x_c at 0.0532 m, outside its stroke [-0.05, 0.05] m by 3.2 mm' (`verb` instead of
    'at', `where` after the value); '' when `value` is inside the stroke (or the axis is
    unlimited)."""
    excess = stroke_excess(axis, value)
    if not excess:
        return ''
    return (f'{axis.name} {verb} {value:.6g} {axis.unit}{where}, outside its stroke {stroke_text(axis)} '
            f'by {amount(excess, axis.unit)}')


def unlimited_range(axis: AxisConfig, period: float) -> float:
    """Largest |position| (rad) accepted on an axis without a stroke (a continuous rotary
    axis) sampled at the control `period` (s): the power of two 2^e up to which float64
    keeps the velocity a servo estimates from consecutive positions exact to the tolerance
    of the limit check. Rounding q to float64 moves it by at most ulp(q)/2, the difference
    q[k+1] - q[k] by at most ulp(q), the velocity by ulp / T; below |q| = 2^e,
    ulp(q) <= 2^(e-52) <= (TOLERANCE - 1) v_max T. Differenced twice or three times
    (acceleration, jerk) the positions carry 2^(n-1) ulp / T^n of rounding, which grows with
    |q|: on fts_lathe's c at 5.01 µs it reaches 0.1 % of the acceleration limit from about
    2^11 rad on and of the jerk limit from 0.25 rad on (test/limit_checks.py allows for it).
    The references' own velocity and acceleration, which the servos feed forward, carry none
    of it: moves are planned relative to their start on these axes (moves._Motion).
    The micromill's c_f (2 pi rad/s, 100 µs) and fts_lathe's c (125.7 rad/s, 5.01 µs):
    2^31 rad; trt_5axis's c (6 rad/s, 1 ms): 2^34 rad. Each lies far beyond what one goal
    can travel (moves.MAX_GOAL_STEPS), so the range refuses absurd values, never the turns
    a spindle makes in a cut: a lathe cuts again from wherever its spindle stopped."""
    ulp = (TOLERANCE - 1.0) * axis.limits.velocity * period
    return math.ldexp(1.0, math.floor(math.log2(ulp)) + 52)


def outside_range(axis: AxisConfig, value: float, period: float) -> str:
    """'c_f at 1e+10 rad, beyond ±2.14748e+09 rad (341782638 turns), the range of its
    unlimited axis ...'; '' when `value` is within unlimited_range (or the axis has a stroke)."""
    if axis.stroke is not None:
        return ''
    bound = unlimited_range(axis, period)
    if abs(value) <= bound:
        return ''
    return (f'{axis.name} at {value:.6g} {axis.unit}, beyond ±{bound:g} {axis.unit} '
            f'({bound / (2 * math.pi):.0f} turns), the range of its unlimited axis (float64 '
            'positions resolve its velocity limit at the control period only within it)')
