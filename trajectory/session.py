"""The trajectory node's session (plain Python, no rclpy): the state machine, goal
bookkeeping and the reference stream behind machine_ctrl/ros/trajectory_node.py, which only
converts messages to the calls below and publishes what the session hands it.

States (:class:`State`; the values are the message of the node's status):

* idle: nothing under way; the stream holds the last position. Goals are accepted only here
  (and only once the machine state is known: :meth:`Session.start_streaming`).
* planning: a tool path is being planned (the node runs the planner; :meth:`Session.path_planned`
  takes its outcome); success starts the motion after a jerk-limited approach from the
  held position, failure refuses the path and returns to idle.
* running: a motion is streamed; :meth:`Session.hold` ramps the feed to 0 (holding),
  :meth:`Session.stop` too and drops the rest (holding until at rest, then idle).
* holding: the motion stands on its path; :meth:`Session.resume` ramps back (running).
* fault: hw_sim reported a fault (:meth:`Session.machine_status`): the motion is dropped,
  the reference at the fault step held, goals refused until hw_sim is healthy again (idle).

A motion that has played out returns the state to idle at the next :meth:`Session.tick`.
Refused goals are counted and the last reason kept (`rejections`: machine_ctrl.diagnostics.Rejections).

Outputs go through an :class:`Outputs` object, in the order they happen: `rows` (a chunk of
the stream to publish), `status` (publish the status now: :meth:`Session.status_values`),
`log` and `warn`. The path planning itself runs outside (the node's planner process runs
:func:`plan_path`).
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Protocol

import numpy as np

from machine_ctrl import contract
from machine_ctrl.diagnostics import Rejections, error_text
from machine_ctrl.model.config import MachineConfig
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.model.reference import Reference
from trajectory import moves, toolpath
from trajectory.planner import plan
from trajectory.stream import ReferenceStream


class State(StrEnum):
    IDLE = 'idle'
    PLANNING = 'planning'
    RUNNING = 'running'
    HOLDING = 'holding'
    FAULT = 'fault'


@dataclass(frozen=True)
class Answer:
    """Answer to a command (a Trigger service): success and the message."""
    success: bool
    message: str


class Outputs(Protocol):
    def rows(self, first: int, positions, velocities, accelerations) -> None:
        """A chunk of the reference stream from control step `first` (lists of row tuples)."""

    def status(self) -> None:
        """The status changed (or is due): publish Session.status_values() now."""

    def log(self, text: str) -> None: ...

    def warn(self, text: str) -> None: ...


_kinematics: dict = {}


def plan_path(machine: MachineConfig, cl: toolpath.CLData, feed: float) -> tuple[Reference | None, str]:
    """Plan a tool path (runs in the node's planner process): (references, '') or (None, the
    reason it cannot be planned). The kinematics are built once per machine and process."""
    kinematics = _kinematics.get(machine.yaml_path) or _kinematics.setdefault(
        machine.yaml_path, Kinematics.from_config(machine))
    result = plan(cl, machine, feed, kinematics=kinematics)
    return (result.plan.reference, '') if result.ok else (None, result.reason)


class Session:
    """One machine's trajectory session (module docstring). `chunk_steps`: rows per chunk
    handed to Outputs.rows; `lookahead`: rows kept streamed ahead of the newest step."""

    def __init__(self, machine: MachineConfig, outputs: Outputs, chunk_steps: int, lookahead: int):
        self.machine = machine
        self.out = outputs
        self.chunk_steps = chunk_steps
        self.lookahead = lookahead
        self.limits = [a.limits for a in machine.axes]
        self.stream: ReferenceStream | None = None
        self.state = State.IDLE
        self.step = 0                       # newest sim step seen
        self.fault = ''
        self.override_setting = 1.0
        self.rejections = Rejections(outputs.warn)
        self.planning_label = ''

    # -- time and streaming ----------------------------------------------------------------
    def start_streaming(self, position, step: int) -> None:
        """The first machine state: hold `position` from `step` on and stream from there."""
        self.stream = ReferenceStream(self.machine.axis_names, self.machine.control_period, position, step)
        self.step = max(self.step, step)
        self._fill()
        self.out.status()

    def tick(self, step: int) -> None:
        """The sim time is at `step`: keep `lookahead` rows streamed ahead; a motion that has
        played out ends (idle)."""
        self.step = max(self.step, step)
        self._fill()
        if self.state in (State.RUNNING, State.HOLDING) and not self.stream.busy(self.step):
            self._set_state(State.IDLE)

    def _fill(self) -> None:
        if self.stream is None:
            return
        while self.stream.next_step < self.step + self.lookahead:
            self.out.rows(*self.stream.take(self.chunk_steps))

    # -- refusals --------------------------------------------------------------------------
    def refuse(self, what: str, reason: str) -> None:
        """Refuse a goal or command: counted (and warned), and the status published with the
        reason. (`rejections.add` counts a refused input without publishing the status.)"""
        self.rejections.add(what, reason)
        self.out.status()

    def may_accept(self, what: str) -> bool:
        """True if a goal can be accepted now (idle, machine state known); else it is refused
        with the reason and False."""
        if self.stream is None:
            reason = f'the machine state is not known yet (no {contract.JOINT_STATES.name})'
        elif self.state == State.FAULT:
            reason = f'machine is faulted ({self.fault}); reset hw_sim first'
        elif self.state != State.IDLE:
            reason = f'busy ({self.state}); one motion at a time'
        else:
            return True
        self.refuse(what, reason)
        return False

    # -- goals -----------------------------------------------------------------------------
    def planning(self, label: str) -> None:
        """A tool path (`label`) accepted (after may_accept) and handed to the planner."""
        self.planning_label = label
        self._set_state(State.PLANNING)

    @property
    def awaiting_plan(self) -> bool:
        """A plan is wanted (False once a fault dropped it)."""
        return self.state == State.PLANNING

    def path_planned(self, reference: Reference | None, failure: str = '') -> None:
        """The planner's outcome: the path's references, or why it failed. Ignored unless
        planning. Starts the approach and the path, or refuses the path (idle)."""
        if not self.awaiting_plan:
            return
        if reference is not None and not failure:
            try:
                here = self.stream.position(self.stream.next_step)
                approach = moves.move_to(self.machine, reference.position[0], moves.AxisState.at_rest(here))
            except Exception as exc:  # noqa: BLE001 - any planning error refuses the goal, the session goes on
                failure = error_text(exc)
            else:
                self._begin(moves.concatenate([approach, reference]), self.planning_label)
                return
        self._set_state(State.IDLE)
        self.refuse('path', f'planning failed: {failure}')

    def accept_joint_goal(self, names, points, times) -> bool:
        """Axis goals (moves.through_waypoints: positions for the axes `names` at each point,
        `times` from the start in s); True if the motion started, else refused."""
        if not self.may_accept('joint goal'):
            return False
        here = self.stream.position(self.stream.next_step)
        try:
            reference = moves.through_waypoints(self.machine, here, names, points, times)
        except ValueError as exc:
            self.refuse('joint goal', str(exc))
            return False
        self._begin(reference, f'joint goal ({len(points)} points)')
        return True

    def home(self) -> Answer:
        """Move to the machine's home at rest (a goal: only while idle)."""
        if not self.may_accept('home'):
            return Answer(False, self.rejections.last)
        here = moves.AxisState.at_rest(self.stream.position(self.stream.next_step))
        self._begin(moves.home(self.machine, here), 'home')
        return Answer(True, f'homing in {len(self.stream.motion.reference)} steps')

    def _begin(self, reference: Reference, label: str) -> None:
        self.stream.start(reference, label, self.limits, self.override_setting)
        self.out.log(f'{label}: {len(reference)} steps from step {self.stream.motion.start}')
        self._set_state(State.RUNNING)
        self._fill()

    # -- feed ------------------------------------------------------------------------------
    def set_feed_override(self, value: float) -> bool:
        """The feed override setting (fraction of the planned feed, for the motion under way
        and the next ones); refused unless finite within [0, 1]."""
        if not (np.isfinite(value) and 0.0 <= value <= 1.0):
            self.refuse('feed override', f'{value!r} is not a fraction within [0, 1]')
            return False
        self.override_setting = float(value)
        if self.state == State.RUNNING:
            self._change_feed(self.override_setting, State.RUNNING)
        self.out.status()
        return True

    def hold(self) -> Answer:
        """Feed hold: ramp to 0, stand on the path (holding; the motion is kept)."""
        return self._answer(self.state == State.RUNNING, lambda: self._change_feed(0.0, State.HOLDING))

    def resume(self) -> Answer:
        """Ramp a held motion back to the override setting (running)."""
        return self._answer(self.state == State.HOLDING and not self.stream.motion.stop_when_still,
                            lambda: self._change_feed(self.override_setting, State.RUNNING))

    def stop(self) -> Answer:
        """Ramp to 0 and drop the rest of the motion (holding, idle once at rest)."""
        return self._answer(self.state in (State.RUNNING, State.HOLDING),
                            lambda: self._change_feed(0.0, State.HOLDING, stop=True))

    def _answer(self, allowed: bool, action) -> Answer:
        if not allowed:
            return Answer(False, f'not applicable while {self.state}')
        try:
            return Answer(True, action())
        except ValueError as exc:
            return Answer(False, str(exc))

    def _change_feed(self, value: float, state: State, stop: bool = False) -> str:
        """Ramp the override of the motion under way from `chunk_steps` after the newest step
        (beyond what the servos may have taken); the stream is re-sent from there."""
        begin = self.stream.set_override(value, self.step + self.chunk_steps, stop)
        self._set_state(state)
        self._fill()
        return f'feed {value:g} from step {begin}'

    # -- faults ----------------------------------------------------------------------------
    def machine_status(self, faulted: bool, reason: str = '', step_text: str = '') -> None:
        """hw_sim's status: `faulted` with the fault `reason` and the fault step (text, as
        hw_sim reports it), or healthy (a reset clears the fault: idle)."""
        if faulted and self.state != State.FAULT:
            self.fault = reason
            if self.stream is not None and step_text.isdigit():
                self.stream.abort(int(step_text) + 1)     # hw_sim stopped at the fault step
                self._fill()
            self._set_state(State.FAULT)
        elif not faulted and self.state == State.FAULT:
            self.fault = ''
            self._set_state(State.IDLE)

    # -- status ----------------------------------------------------------------------------
    def _set_state(self, state: State) -> None:
        if state != self.state:
            self.state = state
            self.out.log(f'state: {state}')
        self.out.status()

    @property
    def faulted(self) -> bool:
        return self.state == State.FAULT

    def status_values(self) -> dict:
        """The status (key -> value), as the node publishes it."""
        stream = self.stream
        motion = stream.motion if stream is not None else None
        return {'state': str(self.state), 'step': self.step,
                'progress': f'{stream.progress(self.step):.4f}' if stream else '0',
                'motion': motion.label if motion else '',
                'motion_start_step': motion.start if motion else '',
                'motion_end_step': motion.end if motion and motion.end is not None else '',
                'streamed_to_step': stream.next_step if stream else '',
                'feed_override': f'{stream.override(self.step):.4f}' if stream else '1',
                'feed_override_setting': self.override_setting,
                'fault': self.fault, 'rejected_goals': self.rejections.count,
                'last_rejection': self.rejections.last}
