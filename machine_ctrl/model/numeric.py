"""Numeric checks shared by the cores and the nodes."""
from __future__ import annotations

import math

# m. A Cartesian coordinate (a G-code word, a tracker's reading) beyond +-this in the workpiece
# frame is a wrong number, refused where it enters, before any arithmetic on it (a 100 m G-code
# line would be a million samples). assumed: 2 m, beyond the reach of every shipped machine
# (the IRB 2400's 1.55 m the largest); the machine's own limits are checked where they apply.
MAX_COORDINATE = 2.0


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
