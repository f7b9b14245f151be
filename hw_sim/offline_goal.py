"""A tool-path goal run offline: what the lock-step graph (`machine-ctrl bringup` + `send`)
does with one goal, without ROS.

The reference stream is made by the trajectory node's own core, trajectory.session.Session,
fed the calls the node makes (machine_ctrl/ros/trajectory_node.py): the first state (hw_sim's
measurement of step 0, where the stream starts holding), the goal (may_accept, planning),
the planner's outcome (trajectory.session.plan_path, the function the node's planner process
runs) at the sim step the node has reached when the plan is in, and then the clock. The
machine is run by :func:`hw_sim.offline.run` from the position hw_sim starts at (its
`initial_position` parameter, default the machine's home).

The one input that is not a function of the goal: the step the motion starts at. The node
starts a motion at the first reference row not yet streamed when the plan is in (the
stream runs `lookahead_steps` rows ahead of the newest /clock step, in chunks of
`chunk_steps` from step 0), and how far the graph has stepped by then depends on the wall
time planning takes. So the start step is a multiple of `chunk_steps`, at least
`lookahead_steps`, and the graph reports it (`motion_start_step` on /trajectory/status);
given it, every row of the stream and every step of the run follow (the hold before it
included: the stream holds the measured position of step 0 at rest).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hw_sim import offline
from hw_sim.simulator import MachineSimulator
from machine_ctrl import parameters
from machine_ctrl.model.config import MachineConfig
from machine_ctrl.model.reference import Reference
from trajectory import toolpath
from trajectory.session import Session, State, plan_path

CLOCK_DECIMATION = parameters.HW_SIM.spec('clock_decimation').default   # the node ticks on /clock


def _default(name: str):
    return parameters.TRAJECTORY.spec(name).default


class _Collected:
    """trajectory.session.Outputs that keeps the streamed chunks and the log lines."""

    def __init__(self):
        self.chunks: list[tuple[int, list, list, list]] = []
        self.lines: list[str] = []

    def rows(self, first, positions, velocities, accelerations) -> None:
        self.chunks.append((first, positions, velocities, accelerations))

    def status(self) -> None:
        pass

    def goal(self, goal) -> None:
        pass

    def log(self, text: str) -> None:
        self.lines.append(text)

    warn = log

    def want_state(self) -> None:
        """Never asked offline: no node stands between the session and the servos."""


@dataclass
class GoalRun:
    """An offline goal run: `reference` = the rows the trajectory node streams (from step
    0; a few chunks beyond `record`), `chunks` = the stream as the node publishes it
    ((first step, positions, velocities, accelerations), in order; a later chunk replaces
    rows from its first step), `record` = the machine's run (offline.RunRecord) of its
    first `steps` steps, the motion's first and last step, the goal's final state."""
    reference: Reference
    chunks: list
    record: offline.RunRecord
    initial_position: tuple[float, ...]
    motion_start: int
    motion_end: int
    goal_state: str
    log: list = field(default_factory=list)


def earliest_start(lookahead: int | None = None, chunk_steps: int | None = None) -> int:
    """The first step a motion can start at: the stream's first row not yet handed out
    when the graph is still at step 0."""
    lookahead = _default('lookahead_steps') if lookahead is None else lookahead
    chunk_steps = _default('chunk_steps') if chunk_steps is None else chunk_steps
    return -(-lookahead // chunk_steps) * chunk_steps


def run_goal(machine: MachineConfig, cl: toolpath.CLData, start_step: int | None = None,
             steps: int | None = None, initial_position=None, feed: float | None = None,
             chunk_steps: int | None = None, lookahead: int | None = None, dual_stage: bool = True) -> GoalRun:
    """Run the tool path `cl` (as the trajectory node receives it) offline; the motion starts
    at `start_step` (default :func:`earliest_start`; must be a step the node can start at:
    module docstring), the run covers `steps` steps (default: to the motion's end and one
    chunk beyond). Node parameters (`feed`, `chunk_steps`, `lookahead`) default to the
    nodes' defaults, `initial_position` to hw_sim's (the machine's home). ValueError when
    the path is refused or cannot start there."""
    feed = _default('feed') if feed is None else feed
    chunk_steps = _default('chunk_steps') if chunk_steps is None else chunk_steps
    lookahead = _default('lookahead_steps') if lookahead is None else lookahead
    initial = tuple(float(v) for v in (machine.home if initial_position is None else initial_position))
    first_state = MachineSimulator(machine, initial_position=initial).measurement.position   # step 0

    out = _Collected()
    session = Session(machine, out, chunk_steps, lookahead)
    session.start_streaming(first_state, 0)
    label = f'path of {len(cl)} points'
    if not session.may_accept('path', label=label):
        raise ValueError(f'path refused: {session.rejections.last}')
    session.planning(label)
    planned, failure = plan_path(machine, cl, feed)

    first = earliest_start(lookahead, chunk_steps)
    start_step = first if start_step is None else int(start_step)
    if start_step < first or start_step % chunk_steps:
        raise ValueError(f'the trajectory node starts a motion at the first row not yet streamed: a multiple of '
                         f'chunk_steps ({chunk_steps}) from {first} on, not {start_step}')
    clock = start_step - lookahead          # the newest /clock step the node has seen when the plan is in
    session.tick(clock)
    session.path_planned(planned, failure)
    if session.state != State.RUNNING:
        raise ValueError(f'path refused: {session.rejections.last}')
    motion = session.stream.motion
    if motion.start != start_step:      # the stream streamed ahead further than the clock asks
        raise ValueError(f'the motion starts at step {motion.start}, not {start_step}')
    while session.state != State.IDLE:
        clock += CLOCK_DECIMATION
        session.tick(clock)
    end = motion.end
    steps = end + 1 + chunk_steps if steps is None else int(steps)
    while session.stream.next_step < steps + chunk_steps:
        clock += CLOCK_DECIMATION
        session.tick(clock)

    rows = session.stream.next_step
    position = np.empty((rows, len(machine.axes)))
    velocity, acceleration = np.empty_like(position), np.empty_like(position)
    for first_row, p, v, a in out.chunks:          # a re-sent chunk replaces rows from its first
        span = slice(first_row, first_row + len(p))
        position[span], velocity[span], acceleration[span] = p, v, a
    reference = Reference(machine.axis_names, machine.control_period, position, velocity, acceleration)
    record = offline.run(machine, reference, dual_stage=dual_stage, steps=steps, initial_position=initial)
    goal = session.goals.goals[-1]
    return GoalRun(reference, out.chunks, record, initial, motion.start, end, goal.state.text, out.lines)
