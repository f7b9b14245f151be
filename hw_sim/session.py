"""What the simulated machine does on each event, without ROS (design.md "Time").

The events: a command message (stamp, axis names, values) from some axes, a recorder's
progress report, a tick of the node's wall-clock timer, a reset. The hw_sim node
(machine_ctrl/ros/hw_sim_node.py) converts messages, passes every event in with the wall
time `now` (s, monotonic) and publishes what the session tells it through
:class:`SessionIO`; the session decides when to advance, re-send, hold, refuse or fault.
Everything here runs on the times passed in, so tests drive it with fake time.

Modes:
* lock-step (:class:`LockStepSession`): step k -> k+1 once every axis has its step-k
  command (:class:`hw_sim.lockstep.LockStep`). While waiting, the current state is re-sent
  every `republish_period` s so nodes that joined late still answer. `min_subscribers` > 0
  holds the machine at step 0 until that many state subscribers are matched (then step 0
  is sent once more and the run begins). `recorder_window` W > 0 (steps) is flow control
  for a recorder (:class:`hw_sim.lockstep.RecorderGate`): once a recorder reports progress,
  the session does not advance from step k while k minus the reported step exceeds W, nor
  from step 0 while the recorder reports that it has written no state yet (step -1); a
  recorder that leaves the graph releases the hold. `wait_for_recorder` also holds step 0
  until a recorder has reported at all (one that reports and leaves releases it too): the
  state subscribers counted for `min_subscribers` may include one that is not the
  recorder's (run137: the trajectory node's reader of the first state, which it drops after
  it, stood in for a recorder not yet discovered, and the bag lacked the first 311 states).
  Holding delays a run, it never changes it.
* paced (:class:`PacedSession`): a step each time the wall clock says one is due (one per
  control period / `real_time_factor`; hw_sim/pacing.py), applying the latest step-k command of each
  axis and, for an axis without one, the command applied before (zero-order hold), counting
  those as missed deadlines; a step's latency (state out to its last command in) and
  hw_sim's own tick lateness as percentiles in the diagnostics, the periods hw_sim itself
  slipped behind the wall clock as overruns.

Faults (the simulator stops: drives off, axes held; the session keeps running and
reporting): a non-finite command, a stroke violation (found by the simulator), a command
missing for `command_timeout` s (lock-step, from step 1 on: at step 0 the graph is still
coming up; never while every command is in hand and the session holds for the recorder;
paced, once ready: an axis without any command, on time or late, that long). In both modes
also a stall of hw_sim itself: its process did not run (SIGSTOP, starved) for more than
`command_timeout` s (:meth:`LockStepSession.watch`, from step 1 on; paced: a timer call
that far behind the wall clock, once ready): whatever the nodes did meanwhile, the machine
stops rather than go on from a gap.
Malformed commands (unknown or duplicate axes, length mismatch, off-grid or future stamps)
and progress reports (off-grid, not a published step) are refused with a reason and change
nothing. A reset clears a fault and restarts the current step from where the axes are
(clipped into their strokes).

Readiness (:attr:`Session.ready`, the node publishes it latched on contract.READY): the
graph is ready once it has completed its first step — in lock-step mode when every axis has
answered step 0 and the machine advanced (so every servo had its first state and its first
reference, and a trajectory node as the reference source had its first state: it streams
only from then on); in paced mode once every axis has been commanded at least once, in time
or late (a graph too slow for its pace is up; its diagnostics show the deadlines it misses).
It stays true (a fault or a reset does not make the graph less up).
"""
from __future__ import annotations

import math
from typing import NamedTuple, Protocol

from machine_ctrl.model.numeric import all_finite
from hw_sim.lockstep import NOTHING_RECORDED, LockStep, RecorderGate
from hw_sim.pacing import LatencyHistogram, WallClockPacer
from hw_sim.simulator import MachineSimulator
from machine_ctrl.contract import NS_PER_SECOND, StepClock, ns_to_seconds
from machine_ctrl.model.errors import InvalidMessage


class SessionIO(Protocol):
    """What a session asks of its node: publishing, logging and two questions about the graph."""

    def publish_state(self, step: int) -> None:
        """Send the state of `step`: the simulator's current measurement (a re-send when the
        step was sent before)."""

    def report_fault(self, reason: str) -> None:
        """The machine has just stopped: say so at once (log, diagnostics)."""

    def refuse_command(self, reason: str) -> None:
        """A command message was refused (nothing changed)."""

    def refuse_progress(self, reason: str) -> None:
        """A recorder progress report was refused (nothing changed)."""

    def log_info(self, text: str) -> None:
        """A change worth a line in the log."""

    def state_subscribers(self) -> int:
        """How many subscribers the states have (asked only while holding at step 0)."""

    def recorder_connected(self) -> bool:
        """Whether the recorder still reports (asked only while holding for it)."""


class Status(NamedTuple):
    """The diagnostics of a session: fault (None when running), one-line message, key values."""
    fault: str | None
    message: str
    values: dict


class Session:
    """What lock-step and paced mode share: the simulator, the step (:class:`LockStep`),
    faults, reset, decimation of the clock and ground-truth streams, the diagnostics."""
    mode = ''

    def __init__(self, sim: MachineSimulator, clock: StepClock, io: SessionIO, *,
                 clock_decimation: int = 1, truth_decimation: int = 0):
        self.sim, self.clock, self.io = sim, clock, io
        self.clock_decimation, self.truth_decimation = clock_decimation, truth_decimation
        self.lockstep = LockStep(tuple(sim.machine.axis_names))
        self.gate = RecorderGate(0)              # window 0: no recorder flow control (paced mode)
        self.missed_deadlines = 0
        self.ready = False                       # the graph has completed its first step
        self._state_sent_at = self._step_started_at = 0.0
        self._watched_at = 0.0                   # wall time of the last watch (stall detection)

    @property
    def step(self) -> int:
        return self.lockstep.step

    @property
    def timer_period(self) -> float:
        """Wall s between the node's calls of :meth:`on_timer`."""
        raise NotImplementedError

    def clock_due(self, step: int) -> bool:
        """Whether the sim time goes out (on /clock) with the state of `step`."""
        return step % self.clock_decimation == 0

    def truth_due(self, step: int) -> bool:
        """Whether the ground truth goes out with the state of `step`."""
        return self.truth_decimation > 0 and step % self.truth_decimation == 0

    def start(self, now: float) -> None:
        """Send the state of the first step."""
        self._watched_at = now
        self._send(now)

    def watch(self, now: float) -> None:
        """Called on every timer of the node (wall time `now`): see LockStepSession."""
        self._watched_at = now

    # -- events ------------------------------------------------------------------------
    def on_command(self, sec: int, nanosec: int, names, values, now: float) -> None:
        """A command message: `values` for the axes `names`, answering the state stamped
        (sec, nanosec)."""
        try:
            step = self.clock.step_at(sec, nanosec)
        except InvalidMessage as exc:           # off the grid, nanosec out of range: counted too
            self.io.refuse_command(self.lockstep.stats.refuse(str(exc)))
            return
        if len(values) == len(names) and not all_finite(values):
            bad = [n for n, v in zip(names, values) if not math.isfinite(v)]
            self.fault(f'non-finite command for {", ".join(bad)}', now)
            return
        self._take(step, names, values, now)

    def on_timer(self, now: float) -> None:
        """The node's wall-clock timer (every :attr:`timer_period` s)."""
        raise NotImplementedError

    def fault(self, reason: str, now: float) -> None:
        """Stop the machine (unless it is stopped already) and report it."""
        if self.sim.fault is None:
            self.sim.stop(reason)
            self.io.report_fault(self.sim.fault)
            self._send(now)

    def reset(self, now: float) -> str:
        """Clear a fault: fresh plants where the axes are (clipped into their strokes), the
        current step taken again. Returns the answer for the caller."""
        held = self.sim.true_position
        clipped = [min(max(q, a.stroke[0]), a.stroke[1]) if a.stroke else q
                   for q, a in zip(held, self.sim.machine.axes)]
        previous = self.sim.fault
        self.sim.reset(initial_position=clipped)
        self.lockstep.restart(self.lockstep.step)
        message = f'reset at step {self.lockstep.step}' + (f' (cleared: {previous})' if previous else '')
        self._send(now)
        return message

    def status(self, now: float) -> Status:
        fault = self.sim.fault
        stats = self.lockstep.stats
        values = {'step': self.lockstep.step, 'mode': self.mode, 'fault': fault or '',
                  'waiting_for': self._waiting_for(),
                  'stale_commands': stats.stale, 'refused_commands': stats.refused,
                  'last_refusal': stats.last_refusal, 'missed_deadlines': self.missed_deadlines,
                  'ready': self.ready}
        message = f'FAULT: {fault}' if fault else f'running, step {self.lockstep.step}'
        return Status(fault, message, values)

    # -- inside ------------------------------------------------------------------------
    def _take(self, step: int, names, values, now: float) -> None:
        raise NotImplementedError

    def _waiting_for(self) -> str:
        return ''

    def _advance(self, commands, now: float) -> None:
        was_ok = self.sim.fault is None
        self.sim.step(commands)
        if was_ok and self.sim.fault is not None:
            self.io.report_fault(self.sim.fault)
        self._send(now)

    def _send(self, now: float, resend: bool = False) -> None:
        self.io.publish_state(self.lockstep.step)
        self._state_sent_at = now
        if not resend:
            self._step_started_at = now          # the command timeout counts from here


class LockStepSession(Session):
    """Lock-step mode: advance once every axis has answered the current step."""
    mode = 'lockstep'

    def __init__(self, sim: MachineSimulator, clock: StepClock, io: SessionIO, *, command_timeout: float = 2.0,
                 republish_period: float = 0.2, min_subscribers: int = 0, recorder_window: int = 0,
                 wait_for_recorder: bool = False, **common):
        super().__init__(sim, clock, io, **common)
        self.command_timeout, self.republish_period = command_timeout, republish_period
        self.min_subscribers = min_subscribers
        self.waiting_for_recorder = wait_for_recorder       # until a recorder's first report
        self.gate = RecorderGate(recorder_window)
        self._start_announced = False

    @property
    def timer_period(self) -> float:
        return min(self.republish_period, self.command_timeout / 4)

    def on_progress(self, sec: int, nanosec: int, now: float) -> None:
        """The recorder has written every state up to the one stamped (sec, nanosec)."""
        try:
            step = self.clock.step_at(sec, nanosec)
            if not NOTHING_RECORDED <= step <= self.lockstep.step:
                raise ValueError(f'progress for step {step}, but the published steps are 0..{self.lockstep.step} '
                                 f'({NOTHING_RECORDED}: none yet)')
        except ValueError as exc:
            self.gate.refuse(str(exc))
            self.io.refuse_progress(str(exc))
            return
        if self.gate.recorded is None:
            self.io.log_info(f'recorder reports progress: holding at most {self.gate.window} steps ahead')
        self.gate.recorded = step
        self.waiting_for_recorder = False
        self.advance_if_ready(now)

    def watch(self, now: float) -> None:
        """hw_sim's own stall: more than `command_timeout` s since the last call (the node
        calls this from each of its timers, every `timer_period` s) means its process did
        not run — stopped (SIGSTOP) or starved. From step 1 on that faults the machine (the
        nodes waited for it, a client may have given up on it): nothing goes on from a gap.
        A shorter gap does not count toward the current step's command timeout beyond one
        timer period: the answers may be in hw_sim's queue, not yet taken (run109: stopped
        4.9 s, hw_sim blamed the servos for a step they had answered)."""
        gap = now - self._watched_at
        self._watched_at = now
        if gap > self.command_timeout and self.lockstep.step > 0:
            self.fault(f'hw_sim stalled: its process did not run for {gap:.1f} s (stopped or starved; '
                       f'limit command_timeout {self.command_timeout:g} s)', now)
        self._step_started_at += max(0.0, gap - self.timer_period)

    def recorder_alive(self, alive: bool, now: float) -> None:
        """The recorder's liveliness (its progress writer's lease, contract.PROGRESS_QOS):
        lost (killed, stopped, hung) releases a hold at once, as a recorder that left the
        graph does; a recorder that comes back holds again from its next progress report."""
        if alive or self.gate.recorded is None:
            return
        self.gate.lost += 1
        self.gate.recorded = None
        self.io.log_info('recorder lost (its liveliness lease ran out): no longer holding for it')
        self.advance_if_ready(now)

    def on_timer(self, now: float) -> None:
        """Watchdog: fault on a command missing too long, else re-send a state waited on;
        then advance if a hold has ended meanwhile. (The node calls :meth:`watch` first.)"""
        if (self.sim.fault is None and self.lockstep.step > 0 and not self.lockstep.complete()
                and now - self._step_started_at > self.command_timeout):
            self.fault(f'missing command for {" ".join(self.lockstep.missing)} '
                       f'(no answer to step {self.lockstep.step} within {self.command_timeout:g} s)', now)
        elif now - self._state_sent_at > self.republish_period:
            self._send(now, resend=True)         # late joiners; idempotent for the nodes
        self.advance_if_ready(now)               # e.g. a recorder matched meanwhile

    def advance_if_ready(self, now: float) -> None:
        if not (self.lockstep.complete() and self.sim.fault is None):
            return
        if self.lockstep.step == 0 and not self._start_announced:
            if self.io.state_subscribers() < self.min_subscribers:
                return                           # hold at step 0 until e.g. a recorder is matched
            if self.waiting_for_recorder:
                return                           # ... until a recorder has reported (bringup --record)
            if self.gate.recorded == NOTHING_RECORDED:
                return                           # ... and until a recorder that is there has state 0
            self._start_announced = True
            self._send(now, resend=True)         # step 0 again, now that every subscriber is there
        if self.holding_for_recorder(now):
            return
        self.ready = True                        # every axis answered a step: the graph steps
        self._advance(self.lockstep.take(), now)

    def holding_for_recorder(self, now: float) -> bool:
        """Whether the recorder is more than recorder_window steps behind (and still there)."""
        holds = self.gate.holds(self.lockstep.step)
        if not holds and self.gate.hold_started is None:
            return False                         # the usual case, every step
        if holds and not self.io.recorder_connected():
            self.io.log_info('recorder left the graph: no longer holding for it')
            self.gate.recorded = None
            holds = False
        self.gate.track(holds, now)
        return holds

    def status(self, now: float) -> Status:
        status = super().status(now)
        gate = self.gate
        if gate.window > 0:
            status.values.update({'recorder_window': gate.window,
                                  'recorder_step': '' if gate.recorded is None else gate.recorded,
                                  'holding_for_recorder': gate.hold_started is not None,
                                  'recorder_holds': gate.hold_count, 'recorder_hold_time': f'{gate.held_for(now):.3f}',
                                  'refused_progress': gate.refused, 'last_progress_refusal': gate.last_refusal})
        return status

    def _take(self, step: int, names, values, now: float) -> None:
        reason = self.lockstep.offer(step, names, values)
        if reason is not None:
            self.io.refuse_command(reason)
            return
        self.advance_if_ready(now)

    def _waiting_for(self) -> str:
        return ' '.join(self.lockstep.missing)


class PacedSession(Session):
    """Paced mode: a step when the wall clock says it is due, whatever has arrived (the
    contract a driver for real hardware implements; hw_sim/pacing.py). Commands are checked
    as in lock-step (:class:`hw_sim.lockstep.LockStep`: malformed or future ones refused);
    one for a step already taken is late, counted as stale and dropped. Once the graph is
    ready, every axis without its command when the next step is due counts as a missed
    deadline, and an axis without any command, on time or late, for `command_timeout` s
    faults the machine (a drive's watchdog: its controller is dead or hung; a reset re-arms
    it). A timer call that finds more than one step due means hw_sim itself ran late: it takes
    one step (the controllers must see every state: a simulator that caught up would skip
    states they answer), counts the periods it slipped as overruns and shifts the schedule
    by as many periods (which count toward no axis's silence); slipped more than
    `command_timeout` s once ready, its process did not run (stopped, starved): the machine
    faults, as in lock-step mode. Before ready a slip
    only shifts the schedule (the graph is still coming up: in one process the other nodes
    are built after hw_sim's timer started)."""
    mode = 'paced'

    def __init__(self, sim: MachineSimulator, clock: StepClock, io: SessionIO, *, real_time_factor: float = 0.1,
                 command_timeout: float = 5.0, **common):
        super().__init__(sim, clock, io, **common)
        self.real_time_factor, self.command_timeout = real_time_factor, command_timeout
        # the node's timer runs on whole ns (rclpy truncates its period): the schedule does too,
        # or it would drift against the timer's calls
        self.pacer = WallClockPacer(ns_to_seconds(int(self.timer_period * NS_PER_SECOND)))
        self.step_latency = LatencyHistogram()
        self.overruns = 0                        # periods hw_sim slipped behind the wall clock
        self._commanded: set[str] = set()        # axes commanded at least once (until ready)
        self._commanded_at: dict[str, float] = {}     # wall time of each axis's newest command
        self._published_at = 0.0                 # wall time the current step's state went out

    @property
    def timer_period(self) -> float:
        return self.clock.period / self.real_time_factor

    def start(self, now: float) -> None:
        self.pacer.restart(now, self.lockstep.step)
        super().start(now)
        self._published_at = now

    def reset(self, now: float) -> str:
        """As in lock-step; the watchdog starts again for every axis."""
        self._commanded_at = dict.fromkeys(self.lockstep.axis_names, now)
        return super().reset(now)

    def on_timer(self, now: float) -> None:
        """Take the next step once due, with the commands in hand, holding the command applied
        over the last period (sim.applied) for each axis without one."""
        step = self.lockstep.step
        slipped = self.pacer.due(now) - step - 1
        if slipped < 0:
            return                               # a timer call before the next step is due
        if self.ready:
            self.pacer.tick_lateness.add(self.pacer.lateness(now, step + 1))
        if slipped:
            if self.ready:
                self.overruns += slipped
                if slipped * self.pacer.period > self.command_timeout:
                    self.fault(f'hw_sim stalled: {slipped * self.pacer.period:.1f} s behind the wall clock (its '
                               f'process did not run: stopped or starved; limit command_timeout '
                               f'{self.command_timeout:g} s)', now)
            self.pacer.slip(now, step + 1)
            # the time hw_sim did not run is no axis's silence: no state went out meanwhile
            for axis in self._commanded_at:
                self._commanded_at[axis] += slipped * self.pacer.period
        waiting = len(self.lockstep.axis_names) - self.lockstep.in_hand
        if self.ready and waiting:               # not all in hand: latency at least this long
            self.step_latency.add(now - self._published_at)
            self.missed_deadlines += waiting
            silent = [a for a in self.lockstep.axis_names if now - self._commanded_at[a] > self.command_timeout]
            if silent:
                self.fault(f'missing command for {" ".join(silent)} (none within {self.command_timeout:g} s)', now)
        self._advance(self.lockstep.take_held(self.sim.applied), now)
        self._published_at = now

    def status(self, now: float) -> Status:
        status = super().status(now)
        status.values.update({'overruns': self.overruns, **self.step_latency.summary('step_latency'),
                              **self.pacer.tick_lateness.summary('tick_lateness')})
        return status

    def _take(self, step: int, names, values, now: float) -> None:
        complete = self.lockstep.complete()
        reason = self.lockstep.offer(step, names, values)
        if reason is not None:
            self.io.refuse_command(reason)
            return
        self._commanded_at.update((n, now) for n in names)     # late ones too: the controller is alive
        if not self.ready:                       # late ones too: the graph is up, if too slow for the pace
            self._commanded.update(names)
            self.ready = len(self._commanded) == len(self.lockstep.axis_names)
        elif step == self.lockstep.step and not complete and self.lockstep.complete():
            self.step_latency.add(now - self._published_at)     # the step's last command
