"""Numeric checks shared by the cores and the nodes."""
from __future__ import annotations

import math


def all_finite(values) -> bool:
    """True if no value is NaN or inf: one C-level sum, through which NaN and inf propagate
    (inf - inf raises); a sum beyond the float range (finite values near 1e308) is checked
    value by value."""
    try:
        return math.isfinite(math.fsum(values))
    except ValueError:                   # inf - inf
        return False
    except OverflowError:                # finite values whose sum leaves the float range
        return all(math.isfinite(v) for v in values)
