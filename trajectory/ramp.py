"""Ramp profiles shared by the streams: the quintic smoothstep S(u) = 10u^3 - 15u^4 + 6u^5,
whose first and second derivatives vanish at both ends (u = 0 and u = 1), so a quantity
blended along it starts and ends with zero rate and zero acceleration.

Used by the feed-override ramps of trajectory/stream.py (one float per control step) and the
compensation on/off blend of compensation/stream.py (an array of steps per chunk). One
implementation for both: the same arithmetic on a float or elementwise on an array.
"""
from __future__ import annotations

import math

import numpy as np

# peaks over [0, 1]: max S' = S'(1/2) = 15/8, max |S''| = S''((3 - sqrt(3)) / 6) = 10/sqrt(3)
SMOOTHSTEP_PEAK_RATE = 15.0 / 8.0
SMOOTHSTEP_PEAK_CURVATURE = 10.0 / math.sqrt(3.0)


def smoothstep(u):
    """S(u), S'(u), S''(u) of the quintic smoothstep, u clipped to [0, 1]; u a float (floats
    out) or an array (arrays out, elementwise)."""
    u = np.clip(u, 0.0, 1.0) if isinstance(u, np.ndarray) else min(max(u, 0.0), 1.0)
    return (u * u * u * (10.0 + u * (-15.0 + 6.0 * u)), 30.0 * u * u * (1.0 - u) ** 2,
            60.0 * u * (1.0 - u) * (1.0 - 2.0 * u))
