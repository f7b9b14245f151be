"""Numeric checks shared by the cores and the nodes."""
from __future__ import annotations

import math


def all_finite(values) -> bool:
    """True if no value is NaN or inf: one C-level sum, through which NaN and inf propagate
    (inf - inf raises; a sum beyond the float range, impossible for real values, counts as
    not finite)."""
    try:
        return math.isfinite(math.fsum(values))
    except (ValueError, OverflowError):
        return False
