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
    0.091 rad -> '91 mrad', 1000 m/s -> '1000 m/s'."""
    size = abs(value)
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
    positions keep the finite-difference jerk of the sampled references exact to the
    tolerance of their limit check. Rounding q to float64 moves it by at most ulp(q)/2, the
    third difference q[k+3] - 3 q[k+2] + 3 q[k+1] - q[k] by at most 4 ulp(q), so the jerk
    estimate by (4 ulp / T³); below |q| = 2^e, ulp(q) <= 2^(e-52) <= (TOLERANCE - 1) j_max T³ / 4.
    The micromill's c_f (2000 rad/s³, 100 µs): 2^11 = 2048 rad (326 turns); trt_5axis's c
    (2000 rad/s³, 1 ms): 2^21 rad."""
    ulp = (TOLERANCE - 1.0) * axis.limits.jerk * period**3 / 4.0
    return math.ldexp(1.0, math.floor(math.log2(ulp)) + 52)


def outside_range(axis: AxisConfig, value: float, period: float) -> str:
    """'c_f at 1e+09 rad, beyond ±2048 rad (326 turns), the range of its unlimited axis
    ...'; '' when `value` is within unlimited_range (or the axis has a stroke)."""
    if axis.stroke is not None:
        return ''
    bound = unlimited_range(axis, period)
    if abs(value) <= bound:
        return ''
    return (f'{axis.name} at {value:.6g} {axis.unit}, beyond ±{bound:g} {axis.unit} '
            f'({bound / (2 * math.pi):.0f} turns), the range of its unlimited axis (float64 '
            'positions resolve its jerk limit at the control period only within it)')
