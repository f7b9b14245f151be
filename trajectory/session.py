"""The trajectory node's session (plain Python, no rclpy): the state machine, goal
bookkeeping and the reference stream behind machine_ctrl/ros/trajectory_node.py, which only
converts messages to the calls below and publishes what the session hands it.

States (:class:`State`; the values are the message of the node's status):

* idle: nothing under way; the stream holds the last position. Goals are accepted only here
  (and only once the machine state is known: :meth:`Session.start_streaming`).
* planning: a tool path is being planned (the node runs the planner; :meth:`Session.path_planned`
  takes its outcome); success starts the motion after a jerk-limited approach from the
  held position, failure refuses the path and returns to idle.
* running: a motion is streamed; :meth:`Session.hold` brings it to rest and keeps it
  (holding), :meth:`Session.stop` too and drops the rest (holding until at rest, then idle).
* holding: the motion stands; :meth:`Session.resume` goes on with it (running).
* fault: hw_sim reported a fault (:meth:`Session.machine_status`): the motion is dropped,
  the reference at the fault step held, goals refused until hw_sim is healthy again (idle).
  Also when hw_sim is lost (:meth:`Session.machine_alive`: its liveliness lease ran out —
  killed, stopped, hung): the goal is aborted with that reason and a motion under way is
  stopped as by :meth:`Session.stop` (hw_sim, if it comes back, faults itself and its fault
  step is then held); the fault clears once hw_sim is alive again and reports healthy.

A motion that has played out returns the state to idle at the next :meth:`Session.tick`.
Refused goals are counted and the last reason kept (`rejections`: machine_ctrl.diagnostics.Rejections).

Goals (trajectory/goals.py): every goal received — path, program, freeform cut, joint goal,
home — is entered in
`goals` (a GoalBook) with its id and the request's stamp: aborted with the reason when
refused; else accepted, executing once the sim time reaches its motion's first step,
succeeded when the motion has played out, canceling / canceled on a stop or cancel,
aborted on a planning failure or a fault. Hold and resume keep the goal executing.

Hold and stop act on the motion `chunk_steps` after the newest step (beyond any row the
servos may have taken), in one of two ways, by the part of the motion there (a motion is a
program of parts: :class:`Program`):

* a point-to-point move (a joint goal's waypoints, home, the approach to a path): Ruckig
  moves run at the axis limits, where a time-warp ramp has almost no headroom and would take
  longer than the move (so the axes would go on to the goal while "holding"). The move is
  cut instead (trajectory/stream.py, `cut`): a time-optimal jerk-limited stop from the
  state the stream gives there (moves.smooth_stop). It may leave the move's line in joint
  space by a little (the axes brake at their own limits); a hold keeps the program, and
  resume plans a move from where it stands to the waypoint it was heading for, then plays
  the rest as planned (a timed waypoint still arrives no earlier than asked, in planned
  time). A stop that would end outside a stroke is refused with the reason.
* a tool path: the time warp (feed override to 0) stops on the path; resume ramps back.

Either way a hold or stop that comes too late — the motion reaches its end before it could
be at rest — is refused with the reason (the goal then succeeds), never answered success.

Outputs go through an :class:`Outputs` object, in the order they happen: `rows` (a chunk of
the stream to publish), `status` (publish the status now: :meth:`Session.status_values`),
`goal` (a goal changed: publish the goal status), `log` and `warn`. The path planning
itself runs outside (the node's planner process runs :func:`plan_path`).
"""
from __future__ import annotations

import os
import signal
from collections import deque
from dataclasses import dataclass
from enum import StrEnum
from typing import Protocol

import numpy as np

from machine_ctrl import contract
from machine_ctrl.diagnostics import PeerLiveliness, Rejections, error_text
from machine_ctrl.model.config import MachineConfig
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.model.reference import Reference
from trajectory import freeform, gcode, moves, part_program, toolpath
from trajectory.goals import Goal, GoalBook, GoalState
from trajectory.planner import plan
from trajectory.stream import ReferenceStream

ZERO_STAMP = (0, 0)


# assumed: 8 lookaheads (24,000 steps by default, 2.4 s of the micromill's sim time, ~6 s of wall
# time at its real-time factor) of the positions handed out are kept: a node's report that its
# reference broke comes within its 1 Hz /diagnostics period, and the row before the break must
# still be there (Session.reference_broken); 1.7 MB for nine axes
KEPT_LOOKAHEADS = 8


class State(StrEnum):
    IDLE = 'idle'
    PLANNING = 'planning'
    RUNNING = 'running'
    HOLDING = 'holding'
    FAULT = 'fault'


class CancelCode:
    """action_msgs/srv/CancelGoal return codes."""
    NONE = 0
    REJECTED = 1
    UNKNOWN_GOAL_ID = 2
    GOAL_TERMINATED = 3


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

    def goal(self, goal: Goal) -> None:
        """`goal` changed state: publish Session.goals.goals and the goal's entry."""

    def log(self, text: str) -> None: ...

    def warn(self, text: str) -> None: ...

    def want_state(self) -> None:
        """Hand the next machine state (one sent after this call) to Session.machine_state
        (asked for when the node between this one and the servos is back: Session.chain_alive;
        and after a stall of this node's own: Session.watch)."""


@dataclass
class Program:
    """A motion as its parts, in order: each a point-to-point move ('move') or a planned
    tool path ('path') ending at rest at `goals[i]` on row `ends[i]` of `reference` (the
    whole motion), to arrive no earlier than `arrivals[i]` s of planned time from the
    motion's start (0: no constraint)."""
    reference: Reference
    kinds: list
    goals: list
    ends: list
    arrivals: list

    def part(self, tau: float) -> int:
        """The part under way at planned time `tau` (rows): the first not yet ended."""
        return next((i for i, end in enumerate(self.ends) if tau < end), len(self.ends) - 1)

    def rest_from(self, i: int, first: Reference, arrival: float) -> Program:
        """The program from part i on, its move i replaced by `first` (which must end at
        goals[i], at rest): the later parts play as planned."""
        end = self.ends[i]
        tail = [Reference(first.axis_names, first.period, self.reference.position[end:],
                          self.reference.velocity[end:], self.reference.acceleration[end:])]
        reference = moves.concatenate([first] + tail) if len(self.ends) > i + 1 else first
        shift = len(first) - 1 - end
        arrivals = [arrival] + [max(0.0, a - self.arrivals[i] + arrival) if a else 0.0 for a in self.arrivals[i + 1:]]
        return Program(reference, self.kinds[i:], self.goals[i:], [e + shift for e in self.ends[i:]], arrivals)


def waypoint_program(reference: Reference, goals, arrivals=None) -> Program:
    """The program of moves through `goals` (each reached at rest; moves.through_waypoints):
    part i ends at the first row at rest (velocity and acceleration exactly 0, as Ruckig
    ends a move) within 1e-9 of goals[i] after the previous part's end."""
    at_rest = (reference.velocity == 0.0).all(axis=1) & (reference.acceleration == 0.0).all(axis=1)
    ends, row = [], 0
    for goal in goals:
        near = at_rest[row:] & (np.abs(reference.position[row:] - goal).max(axis=1) <= 1e-9)
        hits = np.flatnonzero(near)
        row = row + int(hits[0]) if hits.size else len(reference) - 1
        ends.append(row)
    ends[-1] = len(reference) - 1
    return Program(reference, ['move'] * len(goals), [np.asarray(g, float) for g in goals], ends,
                   list(arrivals) if arrivals is not None else [0.0] * len(goals))


_kinematics: dict = {}
# assumed: the planner process's niceness above the node's. Planning is background work:
# where the CPU is short, the nodes that answer every control step come first (a plan then
# takes longer; on an idle core it takes as long).
PLANNER_NICENESS = 5


def planner_process_init() -> None:
    """Start of the node's planner process (it shares the node's process group): Ctrl-C
    (SIGINT to the group) is for the node, which shuts the planner down — the planner
    ignores it rather than die with a KeyboardInterrupt traceback while it waits for work.
    It runs PLANNER_NICENESS below the node's priority."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    os.nice(PLANNER_NICENESS)


def warm_planner() -> None:
    """Load the compiled redundancy resolution (trajectory/resolved_rate.py; compiled here
    the first time after an installation) in the planner process ahead of the first goal."""
    from trajectory import resolved_rate       # here: the node's own process never needs numba
    resolved_rate.warm()


def _kinematics_of(machine: MachineConfig) -> Kinematics:
    """The machine's kinematics, built once per machine and (planner) process."""
    return _kinematics.get(machine.yaml_path) or _kinematics.setdefault(machine.yaml_path,
                                                                         Kinematics.from_config(machine))


def plan_path(machine: MachineConfig, cl: toolpath.CLData, feed: float) -> tuple[Reference | None, str]:
    """Plan a tool path (runs in the node's planner process): (references, '') or (None, the
    reason it cannot be planned)."""
    result = plan(cl, machine, feed, kinematics=_kinematics_of(machine))
    return (result.plan.reference, '') if result.ok else (None, result.reason)


def plan_program_text(machine: MachineConfig, text: str, source: str) -> tuple[Reference | None, str]:
    """A G-code program's text (trajectory/gcode.py; the program topic), in the node's planner
    process: (its pieces' references one after the other, each piece at its program feed,
    exact stops between them: trajectory/part_program.py; '') or (None, the reason, naming
    `source` and the line). A program stop (M0) before the last motion is refused: a program
    sent on a topic runs unattended, with nobody to go on after the stop (``machine-ctrl
    send`` runs such a program, waiting for Enter at each M0)."""
    read = gcode.parse(text, source)
    if not read.ok:
        return None, read.reason
    stop = next((m for m in read.program.motions[:-1] if m.stop_after), None)
    if stop is not None:
        return None, (f'{source}:{stop.line}: an M0 program stop follows this block, and a program sent on '
                      f'{source} runs unattended (machine-ctrl send waits for Enter at an M0)')
    result = part_program.plan_program(read.program, machine, _kinematics_of(machine))
    return (result.reference(), '') if result.ok else (None, result.reason)


def plan_freeform(machine: MachineConfig, surface: str, turning: freeform.Turning, start,
                  lead: float = freeform.LEAD) -> tuple[Reference | None, str]:
    """A freeform cut (freeform.freeform_program) from `start` (positions, at rest), in the
    node's planner process: (the whole motion, '') or (None, the reason). Any error is a reason."""
    try:
        result = freeform.freeform_program(machine, freeform.surface_named(surface), turning,
                                           moves.AxisState.at_rest(start), lead=lead)
    except Exception as exc:  # noqa: BLE001 - a bad surface file or parameter refuses the goal, nothing else
        return None, error_text(exc)
    return (result.reference, '') if result.ok else (None, f'{result.status}: {result.reason}')


class Session:
    """One machine's trajectory session (module docstring). `chunk_steps`: rows per chunk
    handed to Outputs.rows; `lookahead`: rows kept streamed ahead of the newest step."""

    def __init__(self, machine: MachineConfig, outputs: Outputs, chunk_steps: int, lookahead: int,
                 stall_limit: float = contract.STALL_LIMIT):
        self.machine = machine
        self.stall_limit = stall_limit       # s, wall: a longer gap of this node aborts its goal (watch)
        self.out = outputs
        self.chunk_steps = chunk_steps
        self.lookahead = lookahead
        self.limits = [a.limits for a in machine.axes]
        self.stream: ReferenceStream | None = None
        self.state = State.IDLE
        self.step = 0                       # newest sim step seen
        self.clock_step = 0                 # the sim step of the latest tick (a restarted hw_sim starts again at 0)
        self.fault = ''
        self.override_setting = 1.0
        self.rejections = Rejections(outputs.warn)
        self.goals = GoalBook(outputs.goal)
        self.planning_goal: Goal | None = None
        self.program: Program | None = None  # the motion under way, as parts
        self.held: tuple[int, float] | None = None   # a cut hold: (part, planned time) to resume
        self.stopping = False                # a stop or cancel: the goal ends canceled
        # contract.LOSS_CONFIRM, LOSS_CHECK_GAP say why (PeerLiveliness)
        self.hw_sim = PeerLiveliness(contract.LOSS_CONFIRM, contract.LOSS_CHECK_GAP)   # hw_sim's liveliness
        self.chain = PeerLiveliness(contract.LOSS_CONFIRM, contract.LOSS_CHECK_GAP)    # the node between this one and the servos
        self.chain_lost = ''                 # why the reference does not reach the servos
        self.chain_back = ''                 # the node back whose machine state is awaited (chain_alive)
        self._watched_at: float | None = None  # wall time of the last watch (own stall)
        # a stall of its own seen (the goal under way then, the reason), its abort waiting for a fresh
        # machine state (watch, machine_state)
        self._stalled: tuple[Goal | None, str] | None = None
        self._await_fault_step = False       # a fault without hw_sim's fault step yet
        self._handed: deque[tuple[int, np.ndarray]] = deque()   # chunks handed out (first step, positions), oldest first
        self._anchor_step = -1               # the step the stream was last taken up from (start_streaming)
        # node -> the step its reference broke at, and the row handed out for the step before (reference_broken)
        self._breaks: dict[str, tuple[int, list | None]] = {}
        # a break reported during a goal, outside a lost link: (goal, node, step, wall time) (check_breaks)
        self._break_due: tuple[Goal | None, str, int, float] | None = None
        self.rejoining = ''                  # why the stream waits for a machine state after a break (_rejoin)

    @property
    def goal(self) -> Goal | None:
        """The active goal (planning, running or holding), or None."""
        return self.goals.active

    @property
    def planning_label(self) -> str:
        return self.planning_goal.label if self.planning_goal else ''

    # -- time and streaming ----------------------------------------------------------------
    def start_streaming(self, position, step: int, where: str = 'the measured position') -> None:
        """Hold `position` from `step` on and stream from there: the first machine state; after
        the node between this one and the servos is back (:meth:`machine_state`), where the
        servos stand (they held their last row while it was lost: `where` says which position
        that is taken to be), so the stream it forwards moves nothing, and goals are accepted
        again; or the row a servo whose stream broke holds (:meth:`reference_broken`)."""
        self.stream = ReferenceStream(self.machine.axis_names, self.machine.control_period, position, step)
        self.step = max(self.step, step)
        self._anchor_step = step
        if self.chain_back or self.rejoining:
            self.out.log(f'{self.chain_back + " back" if self.chain_back else "reference taken up again"}: holding '
                         f'where the servos stand ({where}, from step {step}); goals accepted again')
            self.chain_lost = self.chain_back = self.rejoining = ''
            if self.state in (State.RUNNING, State.HOLDING):   # a stop still playing out is over: it went nowhere
                self.program, self.held, self.stopping = None, None, False
                self._set_state(State.IDLE)
        self._fill()
        self.out.status()

    def machine_state(self, position, step: int) -> None:
        """A machine state asked for (Outputs.want_state; the first is asked for at the start):
        a stall's abort waiting for the sim time is decided at its `step` (:meth:`watch`);
        the first state starts the stream at `position`; the one after the node between this
        one and the servos came back starts it where the servos hold: the row handed out for
        the step before their break, when they reported one break step (:meth:`reference_broken`),
        else `position` (the measured one: the corrections and offsets added on the way to the
        servos are in it, and would be added once more)."""
        self.step = max(self.step, step)
        stalled, self._stalled = self._stall_waiting() and self._stalled, None
        if stalled:
            self._abort(stalled[1], self.step)
        if self.chain_back:
            broke = {k for k, _ in self._breaks.values() if k > self._anchor_step}
            held = next(row for k, row in self._breaks.values() if k in broke) if len(broke) == 1 else None
            if held is not None:
                self.start_streaming(held, step, f'the row of step {min(broke) - 1}, before their reference broke')
            else:
                self.start_streaming(position, step)
        elif self.stream is None or self.rejoining:
            self.start_streaming(position, step)
        else:
            self._fill()
            self.out.status()

    def reference_broken(self, who: str, step_text: str, now: float) -> None:
        """`who` (a node that follows the reference: a servo, the dual-stage node) reports at
        wall time `now` its stream broken at step `step_text` while moving (model/reference.py
        ReferenceBuffer: it ran out of rows, holds the last one it had and refuses every row
        until one at rest where it holds). Its first report keeps the row handed out for the
        step before, for the stream's next start after the node between this one and the
        servos was lost (:meth:`machine_state`). Otherwise (the stream fell behind, the link
        whole) a break after the stream's last start is mended by taking the stream up again
        from the measured position (:meth:`_rejoin`): at once when idle; during a goal once
        no lost link explains it (:meth:`check_breaks`). Text that is no step is ignored."""
        if not (step_text.isascii() and step_text.isdigit()):
            return
        broke = int(step_text)
        if self._breaks.get(who, (None,))[0] != broke:      # its first report: the row, while still kept
            self._breaks[who] = (broke, self.handed_position(broke - 1))
        if self.chain_lost or self.chain_back or self.rejoining or broke <= self._anchor_step:
            return
        if self.state == State.IDLE:
            self._rejoin(who, broke)
        elif self._break_due is None and self.state in (State.RUNNING, State.HOLDING):
            self._break_due = (self.goal, who, broke, now)

    def check_breaks(self, now: float) -> None:
        """A break reported during a goal (:meth:`reference_broken`) that no lost link has
        explained within a liveliness lease and its confirmation (a lost compensation node,
        whose reason the goal then gets, is the usual cause): the goal is aborted naming the
        node and the stream taken up again where the machine stands (also when the motion
        plays out first, :meth:`tick`: the servo stopped short of its end). The node calls
        this from its timer."""
        if self._break_due is None or now - self._break_due[3] < contract.LIVELINESS_LEASE + contract.LOSS_CONFIRM:
            return
        (goal, who, broke, _), self._break_due = self._break_due, None
        if goal is not self.goal or self.state not in (State.RUNNING, State.HOLDING) or self.chain_lost \
                or self.chain_back or broke <= self._anchor_step:
            return
        self.program, self.held, self.stopping = None, None, False
        self._set_state(State.IDLE)
        if goal is not None:
            self.goals.set(goal, GoalState.ABORTED, self._broken_reason(who, broke))
        self._rejoin(who, broke)

    @staticmethod
    def _broken_reason(who: str, broke: int) -> str:
        return f'{who}: its reference broke at step {broke} while moving (the rows came too late); it holds there'

    def _rejoin(self, who: str, broke: int) -> None:
        """Take the stream up again where the machine stands after `who`'s reference broke at
        step `broke`: nothing streamed and goals refused until a machine state comes
        (Outputs.want_state, :meth:`machine_state`). The measured position, not the row `who`
        holds: other nodes may not have broken (one reader late) and stand elsewhere."""
        self.rejoining = (f'{who}: its reference broke at step {broke} while moving; waiting for the machine state '
                          'to take it up again where the machine stands')
        self.out.warn(self.rejoining)
        self.out.want_state()
        self.out.status()

    def tick(self, step: int) -> None:
        """The sim time is at `step`: keep `lookahead` rows streamed ahead; the goal is
        executing once the sim time reaches its motion; a motion that has played out ends
        (idle; the goal succeeded, or canceled after a stop)."""
        self.step, self.clock_step = max(self.step, step), step
        self._fill()
        if self.state not in (State.RUNNING, State.HOLDING):
            return
        goal, motion = self.goal, self.stream.motion
        if goal is not None and goal.state == GoalState.ACCEPTED and motion is not None and self.step >= motion.start:
            self.goals.set(goal, GoalState.EXECUTING)
        if self.held is None and not self.stream.busy(self.step):
            due, self._break_due = self._break_due, None
            broken = due is not None and due[0] is goal          # a servo stopped short of its end (check_breaks)
            if goal is not None:
                if self.stopping:
                    self.goals.set(goal, GoalState.CANCELED, goal.reason or 'stopped')
                elif broken:
                    self.goals.set(goal, GoalState.ABORTED, self._broken_reason(due[1], due[2]))
                else:
                    self.goals.set(goal, GoalState.SUCCEEDED)
            self.program, self.stopping = None, False
            self._set_state(State.IDLE)
            if broken and not (self.chain_lost or self.chain_back or self.rejoining):
                self._rejoin(due[1], due[2])

    def _send(self, first: int, positions, velocities, accelerations) -> None:
        """Hand a chunk out, and keep the positions handed out over the last KEPT_LOOKAHEADS
        lookaheads (:meth:`handed_position`). Nothing while the node between this one and the servos is
        lost: what it would forward on its return (a stop ending at rest near where the servos
        hold, say) is not where they stand."""
        if self.chain_lost:
            return
        self._handed.append((first, np.array(positions)))
        while len(self._handed) > 1 and \
                self._handed[0][0] + len(self._handed[0][1]) < self.step - KEPT_LOOKAHEADS * self.lookahead:
            self._handed.popleft()
        self.out.rows(first, positions, velocities, accelerations)

    def handed_position(self, step: int) -> list | None:
        """The position this node handed out for `step` last (None: none kept)."""
        for first, positions in reversed(self._handed):
            if first <= step < first + len(positions):
                return positions[step - first].tolist()
        return None

    def _fill(self) -> None:
        """Keep `lookahead` rows streamed ahead; nothing while the node between this one and
        the servos is lost (what it would forward on its return is not where they stand), nor
        while a stall's abort waits for the sim time (rows taken up again from a step of
        before the stall could reach servos that ran out and hold: they would go on moving,
        from where the sim time is now)."""
        if self.stream is None or self.chain_lost or self.rejoining or self._stall_waiting():
            return
        while self.stream.next_step < self.step + self.lookahead:
            self._send(*self.stream.take(self.chunk_steps))

    # -- refusals --------------------------------------------------------------------------
    def refuse(self, what: str, reason: str, stamp: tuple[int, int] | None = None, label: str = '') -> None:
        """Refuse a goal or command: counted (and warned), and the status published with the
        reason. With a `stamp` it is a goal: entered aborted with the reason. (`rejections.add`
        counts a refused input without publishing the status.)"""
        self.rejections.add(what, reason)
        if stamp is not None:
            self.goals.refuse(what, label or what, stamp, self.rejections.last)
        self.out.status()

    def may_accept(self, what: str, stamp: tuple[int, int] | None = ZERO_STAMP, label: str = '') -> bool:
        """True if a goal can be accepted now (idle, machine state known); else it is refused
        with the reason (a goal with `stamp` entered aborted) and False."""
        if self.stream is None:
            reason = f'the machine state is not known yet (no {contract.JOINT_STATES.name})'
        elif self.state == State.FAULT:
            reason = f'machine is faulted ({self.fault}); reset hw_sim first'
        elif self.state != State.IDLE:
            reason = f'busy ({self.state}); one motion at a time'
        elif self.chain_lost or self.rejoining:
            reason = self.chain_lost or self.rejoining
        else:
            return True
        self.refuse(what, reason, stamp, label)
        return False

    # -- goals -----------------------------------------------------------------------------
    def planning(self, label: str, stamp: tuple[int, int] = ZERO_STAMP, kind: str = 'path') -> Goal:
        """A tool path (or a program or a freeform cut: `kind`), `label`, accepted (after
        may_accept) and handed to the planner."""
        self.planning_goal = self.goals.new(kind, label, stamp)
        self.goals.set(self.planning_goal, GoalState.ACCEPTED)
        self._set_state(State.PLANNING)
        return self.planning_goal

    @property
    def awaiting_plan(self) -> bool:
        """A plan is wanted (False once a fault dropped it)."""
        return self.state == State.PLANNING

    def path_planned(self, reference: Reference | None, failure: str = '') -> None:
        """The planner's outcome: the path's references (or a freeform cut's whole motion, which
        starts where the machine is held: its approach is empty), or why it failed. Ignored
        unless planning. Starts the approach and the path, or refuses the path (idle)."""
        if not self.awaiting_plan:
            return
        goal = self.planning_goal
        if reference is not None and not failure:
            try:
                here = self.stream.position(self.stream.next_step)
                approach = moves.move_to(self.machine, reference.position[0], moves.AxisState.at_rest(here))
            except Exception as exc:  # noqa: BLE001 - any planning error refuses the goal, the session goes on
                failure = error_text(exc)
            else:
                whole = moves.concatenate([approach, reference])
                self._begin(Program(whole, ['move', 'path'], [reference.position[0], reference.position[-1]],
                                    [len(approach) - 1, len(whole) - 1], [0.0, 0.0]), self.planning_label)
                return
        self._set_state(State.IDLE)
        self.refuse(goal.kind if goal is not None else 'path', f'planning failed: {failure}')
        if goal is not None:
            self.goals.set(goal, GoalState.ABORTED, self.rejections.last)

    def accept_joint_goal(self, names, points, times, stamp: tuple[int, int] = ZERO_STAMP) -> bool:
        """Axis goals (moves.through_waypoints: positions for the axes `names` at each point,
        `times` from the start in s); True if the motion started, else refused."""
        label = f'joint goal ({len(points)} points)'
        if not self.may_accept('joint goal', stamp, label):
            return False
        here = self.stream.position(self.stream.next_step)
        try:
            reference = moves.through_waypoints(self.machine, here, names, points, times)
        except ValueError as exc:
            self.refuse('joint goal', str(exc), stamp, label)
            return False
        columns = [self.machine.axis_names.index(n) for n in names]
        goals, position = [], np.array(here, dtype=float)
        for values in points:
            position = position.copy()
            position[columns] = values
            goals.append(position)
        timed = any(float(t) != 0.0 for t in times)
        program = waypoint_program(reference, goals, [float(t) for t in times] if timed else None)
        self._begin(program, label, self.goals.new('joint goal', label, stamp))
        return True

    def home(self, stamp: tuple[int, int] = ZERO_STAMP) -> Answer:
        """Move to the machine's home at rest (a goal: only while idle)."""
        if not self.may_accept('home', stamp):
            return Answer(False, self.rejections.last)
        here = moves.AxisState.at_rest(self.stream.position(self.stream.next_step))
        reference = moves.home(self.machine, here)
        goal = self.goals.new('home', 'home', stamp)
        self._begin(waypoint_program(reference, [np.array(self.machine.home, dtype=float)]), 'home', goal)
        return Answer(True, f'homing in {len(self.stream.motion.reference)} steps (goal {goal.uuid})')

    def _begin(self, program: Program, label: str, goal: Goal | None = None) -> None:
        self.stream.start(program.reference, label, self.limits, self.override_setting)
        self.program, self.held, self.stopping = program, None, False
        self.out.log(f'{label}: {len(program.reference)} steps from step {self.stream.motion.start}')
        if goal is not None:
            self.goals.set(goal, GoalState.ACCEPTED)
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
        if self.state == State.RUNNING and not self._stall_waiting():     # the goal is aborted at the state
            try:
                self._change_feed(self.override_setting, State.RUNNING)
            except ValueError as exc:          # e.g. a ramp to 0 too late: the setting is for the next motion
                self.out.log(f'feed override {value:g}: {exc}')
        self.out.status()
        return True

    def hold(self) -> Answer:
        """Feed hold: bring the motion to rest and keep it (holding; module docstring)."""
        if self._stall_waiting():
            return self._stall_answer()
        if self.state != State.RUNNING:
            return Answer(False, f'not applicable while {self.state}')
        return self._halt(keep=True)

    def resume(self) -> Answer:
        """Go on with a held motion (running): a cut move re-planned from where it stands,
        a path ramped back to the override setting."""
        if self._stall_waiting():
            return self._stall_answer()
        if self.state != State.HOLDING or self.stopping:
            return Answer(False, f'not applicable while {self.state}' + (' (stopping)' if self.stopping else ''))
        if self.held is None:
            return self._answer(True, lambda: self._change_feed(self.override_setting, State.RUNNING))
        part, tau = self.held
        program = self.program
        if self.stream.busy(self.stream.next_step):
            return Answer(False, 'still coming to rest; resume once at rest')
        here = self.stream.position(self.stream.next_step)
        arrival = max(0.0, program.arrivals[part] - tau * self.machine.control_period) if program.arrivals[part] else 0.0
        try:
            first = moves.move_to(self.machine, program.goals[part], moves.AxisState.at_rest(here),
                                  minimum_duration=arrival)
        except ValueError as exc:
            return Answer(False, f'cannot resume: {exc}')
        label = self.stream.motion.label
        rest = program.rest_from(part, first, arrival)
        self.stream.start(rest.reference, label, self.limits, self.override_setting)
        self.program, self.held = rest, None
        self.out.log(f'{label}: resumed, {len(rest.reference)} steps from step {self.stream.motion.start}')
        self._set_state(State.RUNNING)
        self._fill()
        return Answer(True, f'resuming from step {self.stream.motion.start}: {len(rest.reference)} steps to the end')

    def stop(self, reason: str = 'stopped') -> Answer:
        """Bring the motion to rest and drop the rest of it (holding until at rest, then
        idle; the goal canceled with `reason`)."""
        if self._stall_waiting():
            return self._stall_answer()
        if self.state == State.HOLDING and not self.stopping:
            if self.held is not None:        # at rest already (or braking): drop the program
                self.held, self.stopping = None, True
                self._canceling(reason)
                self.tick(self.clock_step)
                return Answer(True, 'held motion dropped')
            return self._answer(True, lambda: self._stopping(self._change_feed(0.0, State.HOLDING, stop=True),
                                                             reason))
        if self.state != State.RUNNING:
            return Answer(False, f'not applicable while {self.state}' + (' (stopping)' if self.stopping else ''))
        return self._halt(keep=False, reason=reason)

    def cancel(self, goal_id: bytes | None = None, before: tuple[int, int] | None = None) -> tuple[int, list]:
        """action_msgs/srv/CancelGoal on the active goal: `goal_id` None (all zeros) for
        any, `before` a stamp (None or zero: no limit): cancel a goal accepted with a stamp
        at or before it. Returns (CancelCode, the goals now canceling)."""
        goal = self.goal
        if goal_id is not None:
            if goal is None or goal.id != goal_id:
                known = self.goals.find(goal_id)
                return (CancelCode.GOAL_TERMINATED if known is not None and known.state.terminal
                        else CancelCode.UNKNOWN_GOAL_ID), []
        elif goal is None or (before is not None and before != ZERO_STAMP and goal.stamp > tuple(before)):
            return CancelCode.NONE, []
        if goal.state == GoalState.CANCELING:
            return CancelCode.NONE, [goal]
        if self.state == State.PLANNING:
            self.planning_goal = None
            self._set_state(State.IDLE)
            self.goals.set(goal, GoalState.CANCELED, 'canceled while planning')
            return CancelCode.NONE, [goal]
        answer = self.stop('canceled')
        if not answer.success:
            self.out.warn(f'cancel of goal {goal.uuid} refused: {answer.message}')
            return CancelCode.REJECTED, []
        return CancelCode.NONE, [goal]

    def _answer(self, allowed: bool, action) -> Answer:
        if not allowed:
            return Answer(False, f'not applicable while {self.state}')
        try:
            return Answer(True, action())
        except ValueError as exc:
            return Answer(False, str(exc))

    def _halt(self, keep: bool, reason: str = 'stopped') -> Answer:
        """Hold (`keep`) or stop the running motion from `chunk_steps` after the newest
        step: a move is cut by a time-optimal stop, a path ramps its feed to 0."""
        stream, at = self.stream, self.step + self.chunk_steps
        motion = stream.motion
        begin = max(at, motion.start)
        while stream.next_step <= begin:           # the state there must be streamed
            self._send(*stream.take(self.chunk_steps))
        tau = stream.tau_at(begin)
        if not stream.busy(begin) or tau >= motion.last:
            end = motion.end if motion.end is not None else begin
            return Answer(False, f'too late: the {motion.label} ends at step {end} at rest, before a '
                                 f'{"hold" if keep else "stop"} could act (from step {at})')
        part = self.program.part(tau)
        if self.program.kinds[part] == 'path':
            answer = self._answer(True, lambda: self._change_feed(0.0, State.HOLDING, stop=not keep))
            if answer.success and not keep:
                self._stopping(answer.message, reason)
            return answer
        p, v, a = stream.state(begin)
        try:
            tail = moves.smooth_stop(self.machine, moves.AxisState(tuple(p), tuple(v), tuple(a)))
        except ValueError as exc:
            return Answer(False, f'cannot stop the move: {exc}')
        if part == len(self.program.ends) - 1 and np.abs(tail.position[-1] - self.program.goals[part]).max() <= 1e-9:
            return Answer(False, f'too late: the {motion.label} is braking to its end already (at rest at step '
                                 f'{begin + len(tail) - 1}); a {"hold" if keep else "stop"} from step {at} would end '
                                 'there too')
        stream.cut(begin, tail)
        while stream.busy(stream.next_step):      # the stop streamed to its end: resume starts after it
            self._send(*stream.take(self.chunk_steps))
        self.held = (part, tau) if keep else None
        if not keep:
            self.stopping = True
            self._canceling(reason)
        self._set_state(State.HOLDING)
        self._fill()
        return Answer(True, f'stopping from step {begin}, at rest at step {begin + len(tail) - 1} '
                            f'(time-optimal stop of the move{"; resume goes on to its goal" if keep else ""})')

    def _stopping(self, message: str, reason: str) -> str:
        self.stopping = True
        self._canceling(reason)
        return message

    def _canceling(self, reason: str) -> None:
        if self.goal is not None:
            self.goals.set(self.goal, GoalState.CANCELING, reason)

    def _change_feed(self, value: float, state: State, stop: bool = False) -> str:
        """Ramp the override of the motion under way from `chunk_steps` after the newest step
        (beyond what the servos may have taken); the stream is re-sent from there."""
        begin = self.stream.set_override(value, self.step + self.chunk_steps, stop)
        self._set_state(state)
        self._fill()
        return f'feed {value:g} from step {begin}'

    # -- faults ----------------------------------------------------------------------------
    def watch(self, now: float) -> None:
        """This node's own stall: more than `stall_limit` s (wall, `now`) since the last call —
        the node calls this from its timers (every 0.05 s) and before each /clock step —
        means its process did not run (SIGSTOP, starved), and its clients may have been told
        it is lost (contract.STALL_LIMIT says when). The goal under way is aborted with that
        reason, nothing of it goes on: a motion the servos still have rows of is stopped as by
        :meth:`stop`; one they ran out of (they hold the last row at rest) is held at that
        row. Which of the two it is only the sim time after the stall tells, so the abort
        waits for a machine state sent after it (Outputs.want_state, :meth:`machine_state`),
        and nothing is streamed meanwhile. Not the next /clock step: one taken from a timer
        is from before the stall, and the clock reader's queue holds steps of the stall's
        gap; a stop planned from such a step would take the servos back along the motion.
        The abort is for the goal under way at the stall: one that ended meanwhile (a fault,
        a stop) is not aborted again, nor a later one."""
        gap = 0.0 if self._watched_at is None else now - self._watched_at
        self._watched_at = now
        if gap > self.stall_limit and self.state in (State.RUNNING, State.HOLDING, State.PLANNING):
            self._stalled = (self.goal, f'trajectory stalled: its process did not run for {gap:.1f} s '
                                        '(stopped or starved)')
            self.out.warn(self._stalled[1])
            self.out.want_state()

    def _stall_waiting(self) -> bool:
        """A stall's abort waits for the sim time (:meth:`watch`): its goal is still under way."""
        return self._stalled is not None and self._stalled[0] is self.goal and \
            self.state in (State.RUNNING, State.HOLDING, State.PLANNING)

    def _stall_answer(self) -> Answer:
        """A hold, resume or stop while a stall's abort waits for the sim time: refused (a stop
        planned now would start from a step of before the stall; :meth:`watch`)."""
        return Answer(False, f'{self._stalled[1]}: its goal is aborted once a machine state shows how far the '
                             'servos got')

    def _abort(self, reason: str, newest: int) -> None:
        """Abort the goal under way with `reason` (`newest`: the newest step the graph has
        reached); nothing of it goes on: a motion the servos still have rows of is stopped as
        by :meth:`stop`, one they ran out of (they hold the last row at rest) is held at that
        row."""
        goal = self.goal
        if self.state == State.RUNNING and newest + self.chunk_steps < self.stream.next_step:
            self._halt(keep=False, reason=reason)      # 'too late' is fine: the motion ends at rest
        elif self.stream is not None:
            self.stream.abort(self.stream.next_step)   # the servos ran out: hold the last row handed out
            self._anchor_step = self.stream.next_step     # their break there is mended by it (reference_broken)
        if self.state == State.PLANNING or not (self.stream is not None and self.stream.busy(self.stream.next_step)):
            self.program, self.held, self.stopping, self.planning_goal = None, None, False, None
            self._set_state(State.IDLE)
        else:
            self.held, self.stopping = None, True       # the stop plays out, then idle (tick)
        if goal is not None:
            self.goals.set(goal, GoalState.ABORTED, reason)

    def touch(self, now: float) -> None:
        """A callback of the node ends at wall time `now`: its own duration (a move planned in
        the callback) is no stall (the clients' liveliness is asserted meanwhile by DDS)."""
        self._watched_at = now

    def machine_heard(self, now: float) -> None:
        """A message from hw_sim (a /clock step, or its 1 Hz /diagnostics) came at wall time
        `now`: a liveliness loss reported before it was false (a reader delayed by this node's
        own long callback, or a lease missed in a loaded process)."""
        self.hw_sim.heard(now)

    def machine_alive(self, alive: bool, now: float | None = None) -> None:
        """hw_sim's liveliness (the lease of its latched `ready`): lost is a fault (module
        docstring) whose reason names hw_sim, once confirmed (PeerLiveliness); back again lets
        hw_sim's next healthy status clear it. The node calls this on each liveliness change
        and with alive=False from its timer (`now`: wall time) to confirm."""
        if alive:
            self.hw_sim.alive()
        elif now is not None and self.hw_sim.losing(now):
            self._machine_lost(contract.LIVELINESS_LEASE)

    @property
    def machine_lost(self) -> bool:
        return self.hw_sim.lost

    def chain_heard(self, now: float) -> None:
        """A message from the node between this one and the servos (the compensation node's
        /diagnostics) came at `now` (as :meth:`machine_heard`)."""
        self.chain.heard(now)

    def chain_alive(self, who: str, alive: bool, now: float | None = None) -> None:
        """The liveliness of `who`, the node that carries this node's reference on to the
        servos (the compensation node): lost (confirmed as for hw_sim), the reference no longer
        reaches the servos — they run out of rows and hold — so the goal under way is aborted
        naming it, its motion stopped, nothing more streamed, and goals are refused until it is
        back (its stop is not handed out: what the node would forward on its return is not where
        the servos stand). Back, the stream is taken up again once a machine state comes
        (Outputs.want_state, then :meth:`machine_state`): where the servos held, not where this
        node's stream stood."""
        if alive:
            self.chain.alive()
            if self.chain_lost and not self.chain_back:
                self.chain_back = who
                self.chain_lost = f'{who} back: waiting for the machine state to hold where the servos stand'
                self.out.log(self.chain_lost)
                self.out.want_state()
                self.out.status()
            return
        if now is None or not self.chain.losing(now):
            return
        self.chain_back = ''                 # lost again before its state came: wait for the next return
        self.chain_lost = (f'{who} lost: no sign of life within its {contract.LIVELINESS_LEASE:g} s liveliness '
                           'lease (killed, stopped or hung); the reference does not reach the servos')
        self.out.warn(self.chain_lost)
        if self.state in (State.RUNNING, State.HOLDING, State.PLANNING):
            self._abort(self.chain_lost, self.step)
        self.out.status()

    def _machine_lost(self, lease: float) -> None:
        reason = (f'hw_sim lost: no sign of life within its {lease:g} s liveliness lease '
                  '(killed, stopped or hung)')
        self.out.warn(reason)
        if self.state == State.FAULT:
            self.fault = f'{self.fault}; {reason}'
            self._set_state(State.FAULT)
            return
        goal = self.goal
        if self.state == State.RUNNING:
            self._halt(keep=False, reason=reason)    # 'too late' is fine: the motion ends at rest
        self.fault = reason
        self.program, self.held, self.stopping, self.planning_goal = None, None, False, None
        self._await_fault_step = True
        self._set_state(State.FAULT)
        if goal is not None:
            self.goals.set(goal, GoalState.ABORTED, f'machine faulted: {reason}')

    def machine_status(self, faulted: bool, reason: str = '', step_text: str = '', holds_step: bool = False) -> None:
        """hw_sim's status: `faulted` with the fault `reason` and the fault step (text, as
        hw_sim reports it), or healthy (a reset clears the fault: idle; not while hw_sim is
        lost). `holds_step`: hw_sim holds its step while faulted (lock-step), so a fault reported
        at a step older than the sim time of the latest tick has been reset since. It is a
        report delayed on its way, e.g. queued while a link between hosts was down and
        delivered after the reset (README "Two hosts"), and is ignored: it would abort a goal of
        the reset machine. (The latest tick, not the newest step ever: a restarted hw_sim
        counts from 0 again.)"""
        if (faulted and holds_step and step_text.isascii() and step_text.isdigit()
                and int(step_text) < self.clock_step):
            self.out.log(f'ignored a fault reported at step {step_text}, before step {self.clock_step} the machine '
                         f'has run since (reset): {reason}')
            return
        if faulted and (self.state != State.FAULT or self._await_fault_step):
            self._await_fault_step = False
            self.fault = reason
            if self.stream is not None and step_text.isascii() and step_text.isdigit():
                self.stream.abort(int(step_text) + 1)     # hw_sim stopped at the fault step
                self._fill()
            goal = self.goal
            self.program, self.held, self.stopping, self.planning_goal = None, None, False, None
            self._set_state(State.FAULT)
            if goal is not None:
                self.goals.set(goal, GoalState.ABORTED, f'machine faulted: {reason}')
        elif not faulted and self.state == State.FAULT and not self.machine_lost:
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
        goal = self.goal
        return {'state': str(self.state), 'step': self.step,
                'progress': f'{stream.progress(self.step):.4f}' if stream else '0',
                'motion': motion.label if motion else '',
                'motion_start_step': motion.start if motion else '',
                'motion_end_step': motion.end if motion and motion.end is not None else '',
                'streamed_to_step': stream.next_step if stream else '',
                'feed_override': f'{stream.override(self.step):.4f}' if stream else '1',
                'feed_override_setting': self.override_setting,
                'fault': self.fault, 'rejected_goals': self.rejections.count,
                'last_rejection': self.rejections.last,
                'goal_id': goal.uuid if goal is not None else '',
                'goal_status': goal.state.text if goal is not None else '',
                'reference_lost': self.chain_lost or self.rejoining}
