"""Compensation of a streamed reference, switchable at runtime (the core of
compensation_node; no ROS).

Chunks of reference rows (first control step, positions, velocities, accelerations) are
corrected row by row by :class:`compensation.compensate.Compensator`, so a chunked stream
gives exactly the rows :meth:`Compensator.compensate` gives for the whole trajectory.

Switching on or off never steps the reference: the correction c(t) is blended in or out with
a weight w(k) going 0 -> 1 (or 1 -> 0) along the quintic smoothstep (trajectory/ramp.py)
over RAMP_TIME (ramp_steps control steps), starting at the first step of the next chunk transformed after the switch
(chunks run ahead of the machine, so that is up to the trajectory's lookahead later).
Output rows:
    q + w c,   v + w c' + w' c,   a + w c'' + 2 w' c' + w'' c.
Fully on (w = 1) the rows are the compensator's own; fully off (w = 0) the input rows.
"""
from __future__ import annotations

import numpy as np

from compensation.compensate import Compensator
from trajectory.ramp import smoothstep

# assumed: 0.1 s blend (1000 steps at 10 kHz): blending the largest correction (~5 um) in
# then needs ~0.1 mm/s and ~0.003 m/s^2 of the fine stage, far inside its limits.
RAMP_TIME = 0.1


class CompensationStream:
    def __init__(self, compensator: Compensator, period: float, enabled: bool = True):
        self.compensator, self.period = compensator, period
        self.ramp_steps = max(1, int(round(RAMP_TIME / period)))
        self._ramp = (0, 1.0 if enabled else 0.0, 1.0 if enabled else 0.0)   # (start step, from, to)
        self._pending: bool | None = None
        self.enabled = enabled
        self.chunks = 0
        self.capped_rows = 0
        self.max_residual = 0.0

    def set_enabled(self, enabled: bool) -> None:
        """Switch; takes effect (ramped) from the next chunk on."""
        self.enabled = enabled
        self._pending = enabled

    def weights(self, steps: np.ndarray):
        """w, dw/dt, d2w/dt2 at the given control steps."""
        start, w0, w1 = self._ramp
        s, ds, dds = smoothstep((steps - start) / self.ramp_steps)
        duration = self.ramp_steps * self.period
        return w0 + (w1 - w0) * s, (w1 - w0) * ds / duration, (w1 - w0) * dds / duration ** 2

    def transform(self, first_step: int, positions, velocities, accelerations):
        """Rows out for rows in, plus the Compensation of the rows (None when off)."""
        if self._pending is not None:
            current = float(self.weights(np.array([first_step]))[0][0])
            self._ramp = (first_step, current, 1.0 if self._pending else 0.0)
            self._pending = None
        self.chunks += 1
        steps = first_step + np.arange(len(positions))
        w, dw, ddw = self.weights(steps)
        if not w.any() and not dw.any():
            return np.asarray(positions, float), np.asarray(velocities, float), np.asarray(accelerations, float), None
        q, v, a = (np.array(x, float, ndmin=2) for x in (positions, velocities, accelerations))
        qc, vc, ac, comp = self.compensator.compensate_rows(q, v, a)
        self.capped_rows += int((~comp.converged).sum())
        self.max_residual = max(self.max_residual, float(comp.residual.max(initial=0.0)))
        if (w == 1.0).all() and not dw.any():
            return qc, vc, ac, comp
        c, dc, ddc = qc - q, vc - v, ac - a
        w, dw, ddw = w[:, None], dw[:, None], ddw[:, None]
        return (q + w * c, v + w * dc + dw * c, a + w * ddc + 2 * dw * dc + ddw * c, comp)
