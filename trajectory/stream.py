"""The reference stream of the trajectory node, by control step (design.md "Time": a CNC
interpolator filling the servo buffer ahead of time). Plain Python, no rclpy.

The stream holds the machine at rest at one position until a motion (a sampled
`Reference` that starts at rest there) is started, plays the motion row by row, and holds
its last row at rest afterwards. Rows are handed out once, in order (`take`); a motion
always starts at the first row not yet handed out, from the position held there, so the
stream never jumps. `interrupt` replaces the rest of a running motion from a later step
(feed hold: a smooth stop planned from the state the stream has there), and the rows
from that step on are handed out again.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from machine_ctrl.reference import Reference
from trajectory.moves import AxisState


@dataclass(frozen=True)
class Motion:
    start: int              # control step of the reference's first row
    reference: Reference
    label: str              # what the motion is, for status reports

    @property
    def end(self) -> int:
        """Step of the last row (held afterwards)."""
        return self.start + len(self.reference) - 1


class ReferenceStream:
    def __init__(self, axis_names, period: float, position, first_step: int = 0):
        self.axis_names = tuple(axis_names)
        self.period = period
        self.hold = np.array(position, dtype=float)
        if self.hold.shape != (len(self.axis_names),) or not np.isfinite(self.hold).all():
            raise ValueError(f'hold position needs {len(self.axis_names)} finite values')
        self.motion: Motion | None = None
        self.next_step = first_step          # first row not yet handed out

    def state(self, step: int) -> AxisState:
        """Position, velocity, acceleration the stream gives at `step`."""
        m = self.motion
        if m is not None and step >= m.start:
            k = min(step - m.start, len(m.reference) - 1)
            if k < len(m.reference) - 1:
                r = m.reference
                return AxisState(tuple(r.position[k]), tuple(r.velocity[k]), tuple(r.acceleration[k]))
            return AxisState.at_rest(m.reference.position[-1])
        return AxisState.at_rest(self.hold)

    def take(self, count: int) -> tuple[int, list, list, list]:
        """The next `count` rows: (first step, positions, velocities, accelerations)."""
        first = self.next_step
        rows = [self.state(k) for k in range(first, first + count)]
        self.next_step += count
        return (first, [r.position for r in rows], [r.velocity for r in rows],
                [r.acceleration for r in rows])

    def busy(self, step: int) -> bool:
        """A motion is under way (not yet at its last row) at `step`."""
        return self.motion is not None and step < self.motion.end

    def start(self, reference: Reference, label: str) -> Motion:
        """Play `reference` from the first row not yet handed out. It must start at rest at
        the position held there."""
        if self.busy(self.next_step):
            raise ValueError(f'a motion ({self.motion.label}) is under way')
        here = self.state(self.next_step)
        self._check_start(reference, here)
        self.hold = np.array(here.position)
        self.motion = Motion(self.next_step, reference, label)
        return self.motion

    def interrupt(self, step: int, reference: Reference, label: str) -> Motion:
        """Replace the motion from `step` (>= the first row not yet handed out minus what
        may be re-sent) with `reference`, which must start in the stream's state at `step`;
        rows from `step` on are handed out again."""
        self._check_start(reference, self.state(step))
        self.hold = np.array(self.state(step).position)
        self.motion = Motion(step, reference, label)
        self.next_step = min(self.next_step, step)
        return self.motion

    def _check_start(self, reference: Reference, here: AxisState) -> None:
        if reference.axis_names != self.axis_names or reference.period != self.period:
            raise ValueError('motion is for other axes or another control period')
        gap = np.abs(reference.position[0] - np.array(here.position)).max()
        if gap > 1e-12:
            raise ValueError(f'motion starts {gap:.3g} away from the stream position')

    def progress(self, step: int) -> float:
        """Fraction of the current motion done at `step` (1 when there is none)."""
        m = self.motion
        if m is None or m.end <= m.start:
            return 1.0
        return float(np.clip((step - m.start) / (m.end - m.start), 0.0, 1.0))
