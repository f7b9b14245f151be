"""Sampled axis references: position, velocity and acceleration of every axis at every
control step, the unit the servo consumes (streamed to nodes in chunks, stepped offline)."""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass
class Reference:
    axis_names: tuple[str, ...]
    period: float
    position: np.ndarray        # (steps, axes), m or rad
    velocity: np.ndarray
    acceleration: np.ndarray

    def __post_init__(self):
        shape = (len(self.position), len(self.axis_names))
        for name in ('position', 'velocity', 'acceleration'):
            array = np.ascontiguousarray(getattr(self, name), dtype=float)
            if array.shape != shape:
                raise ValueError(f'reference {name} has shape {array.shape}, expected {shape}')
            if not np.isfinite(array).all():
                raise ValueError(f'reference {name} is not finite')
            setattr(self, name, array)

    def __len__(self) -> int:
        return len(self.position)

    def row(self, k: int) -> tuple[list[float], list[float], list[float]]:
        """Step k; past the end the last position is held at rest (never a jump)."""
        if k < len(self.position):
            return self.position[k].tolist(), self.velocity[k].tolist(), self.acceleration[k].tolist()
        return self.position[-1].tolist(), [0.0] * len(self.axis_names), [0.0] * len(self.axis_names)

    def rows(self, steps: int, block: int = 4096):
        """row(k) for k = 0 .. steps - 1, the arrays converted a block of rows at a time (a
        per-step loop's cheaper path to the same values)."""
        n = len(self.position)
        for first in range(0, min(steps, n), block):
            last = min(first + block, n, steps)
            yield from zip(self.position[first:last].tolist(), self.velocity[first:last].tolist(),
                           self.acceleration[first:last].tolist())
        for k in range(n, steps):
            yield self.row(k)

    def arrays(self, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration of steps 0 .. steps - 1 as arrays (steps, axes):
        :meth:`row` for each step."""
        n = min(steps, len(self.position))
        position, velocity, acceleration = (np.zeros((steps, len(self.axis_names))) for _ in range(3))
        position[:n], velocity[:n], acceleration[:n] = self.position[:n], self.velocity[:n], self.acceleration[:n]
        position[n:] = self.position[-1]
        return position, velocity, acceleration

    @classmethod
    def hold(cls, axis_names, period: float, position, steps: int) -> Reference:
        pos = np.tile(np.asarray(position, float), (steps, 1))
        return cls(tuple(axis_names), period, pos, np.zeros_like(pos), np.zeros_like(pos))


class ReferenceBuffer:
    """Streamed reference rows for some axes, keyed by control step (design.md "Time": the
    servo buffer a CNC interpolator fills ahead). A chunk replaces whatever the buffer held
    from its first step on (a re-plan); a chunk that starts after the buffered end discards
    everything buffered, the steps before it empty. An empty buffer holds the last reference
    position at rest — or, before any reference arrived, the given fallback (the measured
    position) — and counts an underrun; it never jumps (but by up to `rejoin_tolerance` when a
    broken stream is taken up again, below).

    An underrun while the held row moved (velocity or acceleration not zero) breaks the
    stream: the rows that come after it may be stale (queued on their way before the break)
    and would move on from where the machine no longer is. The buffer then holds, refusing
    every row (counted, with the reason) until one at rest within `rejoin_tolerance` of the
    held position on every axis (the stream taken up again where the machine stands)."""

    def __init__(self, axis_names, rejoin_tolerance: float):
        self.axis_names = tuple(axis_names)
        self.rejoin_tolerance = rejoin_tolerance
        self._rows: deque[tuple[list[float], list[float], list[float]]] = deque()
        self._first = 0                      # step of _rows[0]
        self._held: list[float] | None = None
        self._rates: tuple = ((), ())         # velocity, acceleration of the row held (read at an underrun)
        self.underruns = 0
        self.started = False                 # a chunk has arrived at least once
        self.broken_step: int | None = None  # the underrun that broke the stream, while it is broken
        self.refused_rows = 0
        self.last_refusal = ''

    def __len__(self) -> int:
        return len(self._rows)

    @property
    def end_step(self) -> int:
        """First step not buffered."""
        return self._first + len(self._rows)

    def has(self, step: int) -> bool:
        return self._first <= step < self.end_step

    def add(self, first_step: int, positions, velocities, accelerations) -> None:
        self.started = True
        if not self._rows or first_step > self.end_step or first_step < self._first:
            self._rows.clear()
            self._first = first_step
        else:
            for _ in range(self.end_step - first_step):
                self._rows.pop()
        self._rows.extend(zip(positions, velocities, accelerations))

    def take(self, step: int, fallback_position) -> tuple[list[float], list[float], list[float], bool]:
        """Row of `step` (older rows are dropped) and whether the held position was returned
        instead (an underrun, or a row refused while the stream is broken)."""
        while self._rows and self._first < step:
            self._rows.popleft()
            self._first += 1
        if self._rows and self._first == step:
            position, velocity, acceleration = self._rows.popleft()
            self._first += 1
            refusal = None if self.broken_step is None else self._rejoin_refusal(position, velocity, acceleration)
            if refusal is None:
                self.broken_step = None
                self._held, self._rates = position, (velocity, acceleration)
                return position, velocity, acceleration, False
            self.refused_rows += 1
            self.last_refusal = f'step {step}: {refusal}'
        else:
            self.underruns += 1
            if self.broken_step is None and (any(self._rates[0]) or any(self._rates[1])):
                self.broken_step = step
        if self._held is None:
            self._held = list(fallback_position)
        self._rates = ((), ())                # held at rest now
        zeros = [0.0] * len(self.axis_names)
        return list(self._held), zeros, zeros, True

    def _rejoin_refusal(self, position, velocity, acceleration) -> str | None:
        """Why a row does not take the broken stream up again (None: it does)."""
        broke = f'the reference broke at step {self.broken_step} while moving: holding'
        if any(velocity) or any(acceleration):
            return f'{broke}, this row moves (a row at rest is awaited)'
        for name, value, held in zip(self.axis_names, position, self._held):
            if not abs(value - held) <= self.rejoin_tolerance:
                return (f'{broke}, this row is {value - held:+.3g} from the held position on {name} '
                        f'(at most {self.rejoin_tolerance:g} taken up)')
        return None
