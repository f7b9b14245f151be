"""Row-by-row numpy work over many rows, done in blocks that stay in the cache.

One numpy expression over M rows makes each of its temporaries M rows long. At the
planner's sizes (10^5-10^6 samples, each with 10-16 quadrature nodes) those are tens of MB:
the allocator maps each afresh, the kernel faults it in page by page, and every operation
streams it through memory. In blocks of a few thousand rows the temporaries are a few
hundred KB and reused: the same numbers, since the work is row by row, in a fraction of
the time (bench/RESULTS.md, "[5/8] Planning speed").
"""
from __future__ import annotations

import numpy as np

# assumed: rows per block; a block's temporaries (rows x the row's floats) stay within a
# few hundred KB for the row sizes here (1 to 48 floats)
BLOCK = 4096


def in_blocks(function, *arrays, size: int = BLOCK):
    """``function(*arrays)``, computed on blocks of `size` rows (the leading axis of every
    array) and joined along it; a function returning a tuple or a list has each of its
    results joined. The same numbers as one call for a function that works row by row.
    Arrays of no more than `size` rows (or 0-d) go to `function` whole."""
    rows = len(arrays[0]) if np.ndim(arrays[0]) else 0
    if any((len(a) if np.ndim(a) else 0) != rows for a in arrays):
        raise ValueError(f'in_blocks: arrays of {[np.shape(a) for a in arrays]} rows differ')
    if rows <= size:
        return function(*arrays)
    parts = [function(*(a[k:k + size] for a in arrays)) for k in range(0, rows, size)]
    if isinstance(parts[0], (tuple, list)):
        return type(parts[0])(np.concatenate(results) for results in zip(*parts))
    return np.concatenate(parts)
