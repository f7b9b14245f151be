"""Pacing by the wall clock (hw_sim's paced mode, hw_sim/session.py :class:`PacedSession`),
without ROS: which steps are due at a wall time, and how late the graph and hw_sim itself
were, as histograms whose percentiles go on /diagnostics.

Step k is due at ``start + (k - first) * period``; hw_sim takes it at the first timer call
at or after that. A call that finds more than one step due came more than a period late
(hw_sim's own process ran late): real hardware would not have waited, but a simulator that
caught up would skip states the controllers must answer, so hw_sim takes one step, counts
the periods it slipped (*overruns*) and takes that step as due at the newest due time
passed: the schedule keeps its phase (the timer's), only shifted by whole periods.

Two latencies are kept, each in a :class:`LatencyHistogram`:

* **step latency**: from a state's publication to the arrival of the last axis's command
  answering it (the graph's round trip: transport, controllers, transport). A step whose
  commands were not all in hand at its deadline (the next step's tick) is counted with the
  time it had waited by then, a lower bound of its latency: the upper percentiles are then
  at least the period, never flattered.
* **tick lateness**: how long after its due time hw_sim's timer call came (hw_sim's own
  jitter: the executor, the garbage collector, the other nodes of a shared process).
"""
from __future__ import annotations

import bisect
import itertools
import math

# assumed: bins 2 % wide from 1 us to 1 s: a percentile is read within 2 % above the truth
# (10 us at the 0.5 ms target), and ~700 bins keep reading them for the diagnostics
# far below a step's budget; shorter durations fall in the first bin, longer in the last
SMALLEST = 1e-6            # s
RATIO = 1.02
BINS = math.ceil(math.log(1.0 / SMALLEST) / math.log(RATIO))
# assumed: a timer call within a millionth of a period of a step's due time takes that step
# (float rounding of start + k * period), never the next one early
DUE_TOLERANCE = 1e-6


class LatencyHistogram:
    """Counts of durations (s) in geometric bins (:data:`RATIO` wide, from :data:`SMALLEST`
    to 1 s; shorter ones in the first bin, longer in the last) and the exact maximum;
    percentiles read at a bin's upper edge, so never below the truth."""

    _LOG_RATIO = math.log(RATIO)

    def __init__(self):
        self.counts = [0] * BINS
        self.count = 0
        self.maximum = 0.0

    def add(self, duration: float) -> None:
        index = int(math.log(duration / SMALLEST) / self._LOG_RATIO) if duration > SMALLEST else 0
        self.counts[index if index < BINS else BINS - 1] += 1
        self.count += 1
        if duration > self.maximum:
            self.maximum = duration

    def percentile(self, q: float) -> float | None:
        """The q-th percentile (0 < q <= 100): the upper edge of its bin, or the maximum where
        that is smaller (the last bin has no upper edge); None while empty."""
        if not self.count:
            return None
        rank = math.ceil(q / 100.0 * self.count)
        index = bisect.bisect_left(list(itertools.accumulate(self.counts)), rank)
        return self.maximum if index == BINS - 1 else min(self.maximum, SMALLEST * RATIO ** (index + 1))

    def summary(self, name: str) -> dict:
        """Diagnostics values: ``<name>_count`` and ``<name>_p50``, ``_p99``, ``_max`` in s
        ('' while empty)."""
        values: dict = {f'{name}_count': self.count}
        for label, q in (('p50', 50.0), ('p99', 99.0), ('max', 100.0)):
            value = self.percentile(q)
            values[f'{name}_{label}'] = '' if value is None else f'{value:.6f}'
        return values


class WallClockPacer:
    """The schedule of a paced run: step k due at ``start + (k - first) * period`` (wall s),
    with ``first`` the step at :meth:`restart` (the run's start, or a re-based schedule after
    a stall)."""

    def __init__(self, period: float):
        self.period = period
        self.start = 0.0
        self.first = 0
        self.tick_lateness = LatencyHistogram()

    def restart(self, now: float, step: int) -> None:
        """Step `step` is due at `now`; the later ones one period apart."""
        self.start, self.first = now, step

    def due(self, now: float) -> int:
        """The newest step due at wall time `now`."""
        return self.first + math.floor((now - self.start) / self.period + DUE_TOLERANCE)

    def due_time(self, step: int) -> float:
        """The wall time `step` is due."""
        return self.start + (step - self.first) * self.period

    def lateness(self, now: float, step: int) -> float:
        """How long after the due time of `step` wall time `now` is."""
        return now - self.due_time(step)

    def slip(self, now: float, step: int) -> None:
        """`step` is taken late, at `now`: from here on it counts as due at the newest due
        time passed, so the schedule keeps its phase, shifted by whole periods."""
        self.restart(self.due_time(self.due(now)), step)
