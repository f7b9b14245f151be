"""Python's own ``random.Random`` streams inside compiled code: the Mersenne Twister MT19937
(Matsumoto and Nishimura 1998) with CPython's ``random()`` (53 bits from two 32-bit words)
and ``gauss()`` (Box-Muller, the second value kept for the next call), written with numba
so that a compiled loop draws exactly the numbers a ``random.Random`` would, from the state
:meth:`random.Random.getstate` gives.

The simulator's noise streams are ``random.Random`` objects (hw_sim/simulator.py); the
offline runner's compiled loop (hw_sim/compiled_loop.py) continues them here, so a run is
the same bit for bit whichever loop steps it. test/test_compiled_loop.py draws both.

gauss's cos and sin of one angle are compiled into one call of glibc's ``sincos``, which
gives the bits of its ``cos`` and ``sin`` (the ones CPython's math module calls): checked
on 100,000 draws (50,000 angles) per seed by the test, on this platform (x86-64 Linux, glibc).

Layout of a set of streams: ``words`` (streams, 624) int64, the generator's words;
``index`` (streams,) int64, the next word's position; ``spare`` (streams,) float64 and
``has_spare`` (streams,) bool, gauss's kept value.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

_CACHE = True          # numba's on-disk cache (as in trajectory/resolved_rate.py)

N, M = 624, 397
MATRIX_A, UPPER, LOWER = 0x9908B0DF, 0x80000000, 0x7FFFFFFF
TWO_PI = math.tau


@njit(cache=_CACHE)
def _twist(mt):
    """The next 624 words of the generator, in place."""
    for kk in range(N):
        y = (mt[kk] & UPPER) | (mt[(kk + 1) % N] & LOWER)
        mt[kk] = mt[(kk + M) % N] ^ (y >> 1) ^ (MATRIX_A if y & 1 else 0)


@njit(cache=_CACHE)
def _word(words, index, s):
    """The next tempered 32-bit word of stream s."""
    if index[s] >= N:
        _twist(words[s])
        index[s] = 0
    y = words[s, index[s]]
    index[s] += 1
    y ^= y >> 11
    y ^= (y << 7) & 0x9D2C5680
    y ^= (y << 15) & 0xEFC60000
    y ^= y >> 18
    return y


@njit(cache=_CACHE)
def uniform(words, index, s):
    """random.Random.random(): [0, 1) with 53 random bits."""
    a = _word(words, index, s) >> 5
    b = _word(words, index, s) >> 6
    return (a * 67108864.0 + b) * (1.0 / 9007199254740992.0)


@njit(cache=_CACHE)
def gauss(words, index, spare, has_spare, s, sigma):
    """random.Random.gauss(0.0, sigma), the same operations in the same order."""
    if has_spare[s]:
        has_spare[s] = False
        z = spare[s]
    else:
        x2pi = uniform(words, index, s) * TWO_PI
        g2rad = math.sqrt(-2.0 * math.log(1.0 - uniform(words, index, s)))
        z = math.cos(x2pi) * g2rad
        spare[s] = math.sin(x2pi) * g2rad
        has_spare[s] = True
    return 0.0 + z * sigma


def pack(streams) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """words, index, spare, has_spare of `streams` (random.Random objects), in their order."""
    words = np.zeros((len(streams), N), dtype=np.int64)
    index = np.zeros(len(streams), dtype=np.int64)
    spare = np.zeros(len(streams))
    has_spare = np.zeros(len(streams), dtype=np.bool_)
    for s, stream in enumerate(streams):
        _, internal, kept = stream.getstate()
        words[s] = internal[:N]
        index[s] = internal[N]
        if kept is not None:
            spare[s], has_spare[s] = kept, True
    return words, index, spare, has_spare

