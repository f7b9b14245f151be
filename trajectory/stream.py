"""The reference stream of the trajectory node, by control step (design.md "Time": a CNC
interpolator filling the servo buffer ahead of time), with feed override and feed hold.
Plain numpy, no rclpy.

The stream holds the machine at rest until a motion (a sampled `Reference` that starts at
rest at the held position) is started; it plays the motion and holds its last row at rest
afterwards. Rows are handed out once, in order (`take`); a motion starts at the first row
not yet handed out, so the stream never jumps.

Feed override (time warp). The motion is played at a planned-time position tau (in control
periods) that advances by the override k per step (trapezoidal: tau[n+1] = tau[n] +
(k[n] + k[n+1]) / 2, so k = 1 plays the planned rows exactly). Between samples the planned
reference is the quintic Hermite interpolant of its positions, velocities and
accelerations, and the row is

    position r(tau),  velocity k r'(tau),  acceleration k^2 r''(tau) + k' r'(tau)

(' = d/dt of the planned motion; k' = dk/dt). Because the planned motion stays on its path
(a tool path's q(s)), a slower k moves along the same path: feed hold is k -> 0 and stops
on the path; resume is k -> back.

A change of k is a quintic smoothstep ramp (trajectory/ramp.py: k' and k'' zero at both
ends) whose duration fits the added terms k' r' (acceleration), 3 k k' r'' and k'' r' (jerk)
into the headroom the planned motion leaves over the stretch the ramp covers (RampPlanner).
Caveat: where the planned motion is at a limit there, the ramp gets RAMP_LIMIT_SHARE of it,
and since the planned part shrinks only as k^2 (k^3) while k'' r' grows linearly from the
ramp's start, the sum can exceed the jerk limit by a few % in theory; the tests check holds
by finite differences at the control period. A change takes effect `at` a step the caller
chooses (beyond what the servos may have taken) but not before the ramp under way has
ended; rows from there on are handed out again (a re-send). A ramp to 0 (a hold, a stop)
that would not bring the motion to rest before its end is refused (:class:`TooLate`): the
motion would reach its end anyway, and a hold that answered success would be a lie.

Cut (:meth:`ReferenceStream.cut`). Where the planned motion runs at its limits — a
time-optimal point-to-point move (joint goals, home, the approach to a path) accelerates
and brakes at them — a time-warp ramp to 0 gets only the small RAMP_LIMIT_SHARE of the
limits and takes seconds, longer than the move itself. Such a motion is stopped instead by
cutting it: from a step on, the stream plays a `tail` reference that starts in the state
the stream gives there (:meth:`ReferenceStream.state`: position, velocity, acceleration) —
a time-optimal jerk-limited stop planned by the caller — and the motion ends where the
tail ends.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from machine_ctrl.model.reference import Reference
from trajectory.ramp import SMOOTHSTEP_PEAK_CURVATURE, SMOOTHSTEP_PEAK_RATE, smoothstep

# assumed: where the planned motion leaves no headroom, a ramp's extra acceleration and jerk
# terms may use 5 % of each axis's limit (see the module docstring).
RAMP_LIMIT_SHARE = 0.05
# assumed: no ramp shorter than 50 ms (a feed hold of a slow motion still looks smooth).
MIN_RAMP_TIME = 0.05


class RampPlanner:
    """Ramp durations for one planned motion (limits: objects with `acceleration` and
    `jerk`, one per axis).

    Over the stretch a ramp covers, the planned motion has peaks v, a, j (of |dr/dt|,
    |d2r/dt2|, |d3r/dt3| per axis); scaled by k <= 1 it leaves the headroom A - a and J - j
    (at least RAMP_LIMIT_SHARE of the limits A, J), which the ramp's own terms must fit in:
    |k'| v <= A - a and 3 |k'| a + |k''| v <= J - j, with the smoothstep's peaks
    |k'| = 15/8 |dk| / D and |k''| = 10/sqrt(3) |dk| / D^2 for a ramp of duration D."""

    def __init__(self, reference: Reference, limits):
        self.speed = np.abs(reference.velocity)
        self.accel = np.abs(reference.acceleration)
        jerk = np.abs(np.diff(reference.acceleration, axis=0)) / reference.period
        self.jerk = np.vstack([jerk, jerk[-1:]]) if len(jerk) else np.zeros_like(self.accel)
        self.acc_limit = np.array([lim.acceleration for lim in limits])
        self.jerk_limit = np.array([lim.jerk for lim in limits])

    def duration(self, tau: float, k0: float, k1: float, period: float) -> float:
        """Seconds for a ramp of k from k0 to k1 starting at planned time tau (periods):
        the shortest of a geometric series of candidates (from MIN_RAMP_TIME up to what the
        whole motion's peaks need) that suffices for the peaks of the stretch it covers
        (planned time (k0 + k1) / 2 * duration)."""
        first, dk = int(tau), abs(k1 - k0)
        whole = self._duration(first, len(self.speed), dk)
        candidate = MIN_RAMP_TIME
        while candidate < whole:
            last = min(len(self.speed), first + 2 + int(candidate * 0.5 * (k0 + k1) / period))
            if self._duration(first, last, dk) <= candidate:
                return candidate
            candidate *= 1.25
        return whole

    def _duration(self, first: int, last: int, dk: float) -> float:
        v, a, j = (x[first:last].max(axis=0) for x in (self.speed, self.accel, self.jerk))
        room_a = np.maximum(self.acc_limit - a, RAMP_LIMIT_SHARE * self.acc_limit)
        room_j = np.maximum(self.jerk_limit - j, RAMP_LIMIT_SHARE * self.jerk_limit)
        by_acc = SMOOTHSTEP_PEAK_RATE * dk * v / room_a
        b = 3.0 * SMOOTHSTEP_PEAK_RATE * dk * a           # b / D + c / D^2 <= room_j
        c = SMOOTHSTEP_PEAK_CURVATURE * dk * v
        by_jerk = (b + np.sqrt(b * b + 4.0 * room_j * c)) / (2.0 * room_j)
        return float(max(MIN_RAMP_TIME, by_acc.max(), by_jerk.max()))


@dataclass
class Ramp:
    """k from k0 to k1 over steps [start, start + steps] (smoothstep)."""
    start: int
    k0: float
    k1: float
    steps: int

    @property
    def end(self) -> int:
        return self.start + self.steps

    def at(self, step: int, period: float) -> tuple[float, float, float]:
        """k, dk/dt, d2k/dt2 at `step`."""
        if self.steps <= 0 or step >= self.end:
            return self.k1, 0.0, 0.0
        s, s1, s2 = smoothstep((step - self.start) / self.steps)
        duration = self.steps * period
        dk = self.k1 - self.k0
        return self.k0 + dk * s, dk * s1 / duration, dk * s2 / duration ** 2


class TooLate(ValueError):
    """A ramp to 0 asked for where the motion reaches its end before it could be at rest."""


@dataclass
class Motion:
    start: int                      # control step of the first row
    reference: Reference
    label: str
    ramps: RampPlanner
    ramp: Ramp
    tau: list = field(default_factory=list)     # planned time (periods) of each streamed step
    end: int | None = None          # step of the last row, once streamed that far
    stop_when_still: bool = False   # a stop: the motion ends where the ramp to 0 does
    cut: int | None = None          # from this step on the motion plays `tail` instead (a stop)
    tail: Reference | None = None

    @property
    def last(self) -> float:
        return float(len(self.reference) - 1)


class ReferenceStream:
    def __init__(self, axis_names, period: float, position, first_step: int = 0):
        self.axis_names = tuple(axis_names)
        self.period = period
        self.hold = np.array(position, dtype=float)
        if self.hold.shape != (len(self.axis_names),) or not np.isfinite(self.hold).all():
            raise ValueError(f'hold position needs {len(self.axis_names)} finite values')
        self.motion: Motion | None = None
        self.next_step = first_step          # first row not yet handed out

    # -- rows ------------------------------------------------------------------------------
    def take(self, count: int) -> tuple[int, list, list, list]:
        """The next `count` rows: (first step, positions, velocities, accelerations)."""
        first = self.next_step
        rows = [self._row(k) for k in range(first, first + count)]
        self.next_step += count
        return first, [r[0] for r in rows], [r[1] for r in rows], [r[2] for r in rows]

    def _row(self, step: int):
        m = self.motion
        zeros = (0.0,) * len(self.hold)
        if m is None or step < m.start:
            return tuple(self.hold), zeros, zeros
        if m.cut is not None and step >= m.cut:
            i, last = step - m.cut, len(m.tail) - 1
            if i >= last:
                m.end = m.cut + last if m.end is None else m.end
                return tuple(m.tail.position[last]), zeros, zeros
            return tuple(m.tail.position[i]), tuple(m.tail.velocity[i]), tuple(m.tail.acceleration[i])
        if m.end is not None and step >= m.end:
            return tuple(self.position(m.end)), zeros, zeros
        n = step - m.start
        if n == len(m.tau):
            m.tau.append(self._advance(m, step))
        tau = m.tau[n]
        k, dk, _ = m.ramp.at(step, self.period)
        if tau >= m.last or (m.stop_when_still and k == 0.0 and step >= m.ramp.end):
            m.end = step
            return tuple(self.position(step)), zeros, zeros
        p, v, a = self._sample(m, tau)
        return tuple(p), tuple(k * v), tuple(k * k * a + dk * v)

    def _advance(self, m: Motion, step: int) -> float:
        if step == m.start:
            return 0.0
        k_prev = m.ramp.at(step - 1, self.period)[0]
        k_now = m.ramp.at(step, self.period)[0]
        return min(m.tau[-1] + 0.5 * (k_prev + k_now), m.last)

    def _sample(self, m: Motion, tau: float):
        """Planned position, velocity, acceleration at planned time tau (periods)."""
        r = m.reference
        j = int(tau)
        u = tau - j
        if u == 0.0 or j >= len(r) - 1:
            j = min(j, len(r) - 1)
            return r.position[j], r.velocity[j], r.acceleration[j]
        return _hermite(r, j, u, self.period)

    # -- motions ---------------------------------------------------------------------------
    def busy(self, step: int) -> bool:
        """A motion is under way (or held) at `step`."""
        m = self.motion
        return m is not None and (m.end is None or step < m.end)

    def position(self, step: int) -> np.ndarray:
        """Position the stream gives at a step already handed out (or the hold after)."""
        m = self.motion
        if m is None or step < m.start:
            return self.hold.copy()
        if m.cut is not None and step >= m.cut:
            return m.tail.position[min(step - m.cut, len(m.tail) - 1)].copy()
        n = min(step - m.start, len(m.tau) - 1)
        return np.array(self._sample(m, m.tau[n])[0]) if n >= 0 else self.hold.copy()

    def start(self, reference: Reference, label: str, limits, override: float = 1.0) -> Motion:
        """Play `reference` from the first row not yet handed out, at feed override
        `override`. It must start at rest at the position held there."""
        if self.busy(self.next_step):
            raise ValueError(f'a motion ({self.motion.label}) is under way')
        here = self.position(self.next_step)
        if reference.axis_names != self.axis_names or reference.period != self.period:
            raise ValueError('motion is for other axes or another control period')
        gap = np.abs(reference.position[0] - here).max()
        if gap > 1e-12:
            raise ValueError(f'motion starts {gap:.3g} away from the stream position')
        self.hold = here
        self.motion = Motion(self.next_step, reference, label, RampPlanner(reference, limits),
                             Ramp(self.next_step, override, override, 0))
        return self.motion

    def state(self, step: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration the stream gives at `step`, a step already
        handed out (or any step of the hold after the motion); ValueError for a row of the
        motion not handed out yet."""
        m = self.motion
        zeros = np.zeros(len(self.hold))
        if m is None or step < m.start:
            return self.hold.copy(), zeros, zeros.copy()
        if m.cut is not None and step >= m.cut:
            i = step - m.cut
            if i >= len(m.tail) - 1:
                return m.tail.position[-1].copy(), zeros, zeros.copy()
            return m.tail.position[i].copy(), m.tail.velocity[i].copy(), m.tail.acceleration[i].copy()
        if m.end is not None and step >= m.end:
            return self.position(m.end), zeros, zeros.copy()
        n = step - m.start
        if n >= len(m.tau):
            raise ValueError(f'step {step} is not streamed yet')
        tau = m.tau[n]
        k, dk, _ = m.ramp.at(step, self.period)
        if tau >= m.last:
            return self.position(step), zeros, zeros.copy()
        p, v, a = self._sample(m, tau)
        return np.array(p), k * np.asarray(v), k * k * np.asarray(a) + dk * np.asarray(v)

    def tau_at(self, step: int) -> float:
        """Planned time (periods) of the motion at `step` (extrapolated at the override
        there beyond the rows handed out)."""
        m = self.motion
        if m is None:
            return 0.0
        n = step - m.start
        if n <= 0:
            return 0.0
        if n < len(m.tau):
            return m.tau[n]
        known, tau = (len(m.tau) - 1, m.tau[-1]) if m.tau else (0, 0.0)
        return min(tau + (n - known) * m.ramp.at(step, self.period)[0], m.last)

    def set_override(self, value: float, at: int, stop: bool = False) -> int:
        """Ramp the feed override to `value` (0..1) from step `at` (or from the end of a
        ramp under way); with `stop`, the motion ends where it comes to rest (value 0).
        Returns the step the ramp starts at. Rows from there are handed out again.
        :class:`TooLate` (nothing changed) for a ramp to 0 that would not come to rest
        before the motion's end."""
        m = self.motion
        if m is None or not self.busy(at):
            raise ValueError('no motion under way')
        if m.cut is not None:
            raise ValueError('the motion is being stopped')
        if not 0.0 <= value <= 1.0:
            raise ValueError(f'feed override must be within [0, 1], got {value!r}')
        begin = max(at, m.ramp.end, m.start)
        k0 = m.ramp.at(begin, self.period)[0]
        tau = self.tau_at(begin)
        steps = 0 if value == k0 else round(m.ramps.duration(tau, k0, value, self.period) / self.period)
        if value == 0.0 and k0 > 0.0 and tau + 0.5 * k0 * steps >= m.last:
            end = begin + (m.last - tau) / k0
            raise TooLate(f'too late: the motion reaches its end (about step {end:.0f}) before a ramp to 0 from '
                          f'step {begin} could bring it to rest')
        m.ramp = Ramp(begin, k0, value, steps)
        m.stop_when_still = stop
        m.end = None if m.end is None or m.end > begin else m.end
        del m.tau[begin - m.start + 1:]
        self.next_step = min(self.next_step, begin + 1)
        return begin

    def cut(self, at: int, tail: Reference) -> int:
        """Play `tail` from step `at` (or the motion's first step, if later) on instead of
        the rest of the motion: a stop planned from :meth:`state` there (its first row is
        that state). The motion ends where the tail does; its progress stays where it was
        cut, the override reported ramps to 0 over the tail. Rows after the cut step are
        handed out again. Returns the cut step."""
        m = self.motion
        if m is None or not self.busy(at):
            raise ValueError('no motion under way')
        if tail.axis_names != self.axis_names or tail.period != self.period:
            raise ValueError('stop is for other axes or another control period')
        begin = max(at, m.start)
        k0 = m.ramp.at(begin, self.period)[0]
        m.cut, m.tail, m.end, m.stop_when_still = begin, tail, None, False
        del m.tau[begin - m.start + 1:]
        m.ramp = Ramp(begin, k0, 0.0, len(tail) - 1)
        self.next_step = min(self.next_step, begin + 1)
        return begin

    def abort(self, at: int) -> None:
        """Drop the motion from step `at` on and hold where the stream was at `at`."""
        if self.motion is not None:
            self.hold = self.position(at)
            self.motion = None
        self.next_step = min(self.next_step, at)

    def override(self, step: int) -> float:
        return self.motion.ramp.at(step, self.period)[0] if self.motion is not None else 1.0

    def progress(self, step: int) -> float:
        """Fraction of the current motion's planned time done at `step` (1 when none)."""
        m = self.motion
        if m is None or m.last <= 0 or not m.tau:
            return 1.0 if m is None or m.last <= 0 else 0.0
        n = min(max(step - m.start, 0), len(m.tau) - 1)
        return float(m.tau[n] / m.last)


def _hermite(r: Reference, j: int, u: float, period: float):
    """Quintic Hermite interpolation between samples j and j+1 at fraction u: position,
    velocity, acceleration (per second)."""
    t = period
    p0, p1 = r.position[j], r.position[j + 1]
    v0, v1 = r.velocity[j] * t, r.velocity[j + 1] * t
    a0, a1 = r.acceleration[j] * t * t, r.acceleration[j + 1] * t * t
    # coefficients of p(u) = c0 + c1 u + ... + c5 u^5 matching p, p', p'' at u = 0 and 1
    d = p1 - p0 - v0 - 0.5 * a0
    e = v1 - v0 - a0
    f = a1 - a0
    c3 = 10.0 * d - 4.0 * e + 0.5 * f
    c4 = -15.0 * d + 7.0 * e - f
    c5 = 6.0 * d - 3.0 * e + 0.5 * f
    p = p0 + u * (v0 + u * (0.5 * a0 + u * (c3 + u * (c4 + u * c5))))
    dp = v0 + u * (a0 + u * (3.0 * c3 + u * (4.0 * c4 + u * 5.0 * c5)))
    ddp = a0 + u * (6.0 * c3 + u * (12.0 * c4 + u * 20.0 * c5))
    return p, dp / t, ddp / (t * t)
