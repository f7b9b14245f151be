"""Base of the nodes that answer every lock-step state from the streamed reference (the
servo and dual-stage nodes): the reference buffer fed from /reference and the /joint_states
subscription (both raw, decoded by machine_ctrl.recording.cdr), one answer per step (StepResponder)
and the count of refused messages."""
from __future__ import annotations

from rclpy.node import Node

from machine_ctrl import contract, parameters
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.recording.cdr import JointStateData
from machine_ctrl.ros.node_common import (StepResponder, rejections, subscribe_joint_states, subscribe_reference,
                                          use_sim_time)
from machine_ctrl.ros.node_parameters import declare_parameters
from machine_ctrl.model.reference import ReferenceBuffer


class StepNode(Node):
    def __init__(self, name: str, table: parameters.NodeParameters, **kwargs):
        """`table`: the node's parameters, which hold `input_timeout`."""
        super().__init__(name, **kwargs)
        use_sim_time(self, lambda reason: self.rejections.add('clock', reason))
        self.input_timeout = declare_parameters(self, table, names=('input_timeout',)).input_timeout
        self.rejections = rejections(self)

    def start_stepping(self, machine, reference_axes, publisher, ready, compute, streaming) -> None:
        """Subscribe /joint_states and /reference; `ready`, `compute`, `streaming` as in
        StepResponder."""
        self.clock = ros_io.StepClock.of(machine)
        self.reference_axes = tuple(reference_axes)
        self.responder = StepResponder(self, publisher, ready, compute, self.input_timeout, streaming)
        subscribe_joint_states(self, contract.JOINT_STATES.name, self.on_state,
                               lambda reason: self.rejections.add('state', reason))
        self.reference_reader = subscribe_reference(
            self, contract.REFERENCE.name, self.clock, self.reference_axes, self.on_reference,
            lambda reason: self.rejections.add('reference', reason))

    def waiting_for(self) -> str:
        """What the node waits for before it answers the newest state, for /diagnostics: ''
        when it is not waiting; the reference stream if it never delivered, with the writers its
        reader is matched with (:func:`matched`); `missing_inputs()` of a subclass."""
        if not self.responder.waiting:
            return ''
        missing = [] if self.buffer.started else [
            f'{contract.REFERENCE.name} (never received; {matched(self.reference_reader)})']
        return ', '.join(missing + self.missing_inputs()) or 'inputs of the current step'

    def missing_inputs(self) -> list[str]:
        """The per-step inputs besides the state and the reference that are missing."""
        return []

    def reference_values(self) -> dict:
        """The reference buffer's state for /diagnostics: underruns, and a stream broken while
        moving (ReferenceBuffer: the step it broke at, '' when it is not; the rows refused)."""
        buffer = self.buffer
        return {'reference_underruns': buffer.underruns, 'buffered_steps': len(buffer),
                'reference_broken_step': '' if buffer.broken_step is None else buffer.broken_step,
                'refused_reference_rows': buffer.refused_rows, 'last_refused_reference_row': buffer.last_refusal}

    def reference_problems(self) -> list[str]:
        """The reference buffer's problems so far, as text for the status message."""
        buffer = self.buffer
        problems = [f'{buffer.underruns} reference underruns'] if buffer.underruns else []
        if buffer.broken_step is not None:
            problems.append(f'reference broken at step {buffer.broken_step} while moving: holding until a row at rest '
                            'where it holds')
        if buffer.refused_rows:
            problems.append(f'{buffer.refused_rows} reference rows refused')
        return problems

    def make_buffer(self, axes) -> ReferenceBuffer:
        self.buffer = ReferenceBuffer(axes, contract.REJOIN_TOLERANCE)
        return self.buffer

    def on_reference(self, first_step: int, positions, velocities, accelerations) -> None:
        self.buffer.add(first_step, positions, velocities, accelerations)
        self.responder.poke()

    def on_state(self, msg: JointStateData) -> None:
        try:
            self.responder.on_state(self.clock.step_at(msg.sec, msg.nanosec), msg)
        except ros_io.InvalidMessage as exc:
            self.rejections.add('state', str(exc))

    def positions(self, msg: JointStateData, axes, velocities: bool = False):
        """Measured positions (and velocities) of `axes` from a state, or None if refused."""
        try:
            position = ros_io.select(msg, 'position', axes)
            return (position, ros_io.select(msg, 'velocity', axes)) if velocities else position
        except ros_io.InvalidMessage as exc:
            self.rejections.add('state', str(exc))
            return None


def matched(reader) -> str:
    """How many writers a subscription is matched with, as text: none means the writing node
    is gone or not yet discovered; one that sends nothing through a match is a writer that does
    not run or a transport that does not deliver (a loaded run once saw a restarted
    dual_stage's offsets never reach servo_fine). A killed node's writer stays matched until
    its DDS participant's lease runs out."""
    count = reader.get_publisher_count()
    return f'{count} writer{"" if count == 1 else "s"} matched'


class StepInput:
    """A per-step input stream besides the state (the offsets of the dual-stage node, the
    accelerometer readings): values by step until their step is computed, whether it has ever
    delivered, and the steps left unanswered for want of it; what it waits for says how many
    writers its reader (`reader`, the node's subscription) is matched with."""

    def __init__(self, topic: str):
        self.topic = topic
        self.reader = None                 # the node's subscription, once made
        self.pending: dict[int, object] = {}
        self.started = False
        self.missing = 0                   # steps left unanswered for want of this input
        self.lost_step: int | None = None  # the newest such step

    # assumed: 10,000 steps (1 s at 10 kHz) is far more than lock-step lets a stream run ahead
    # (hw_sim waits for every answer); a stream that does (paced hw_sim before any reference
    # arrives) keeps only its newest steps
    WINDOW = 10_000

    def put(self, step: int, value) -> None:
        self.pending[step] = value
        self.started = True
        if len(self.pending) > self.WINDOW:
            del self.pending[next(iter(self.pending))]        # the oldest put

    def take(self, step: int):
        """The value of `step` (None if it has none), dropping it and every older one."""
        value = self.pending.pop(step, None)
        for old in [s for s in self.pending if s < step]:
            del self.pending[old]
        return value

    def miss(self, step: int) -> None:
        self.missing += 1
        self.lost_step = step

    def waiting_text(self, answered_step: int, timeout: float) -> list[str]:
        if not self.started:
            return [f'{self.topic} (never received; {matched(self.reader)})']
        if self.lost_step is not None and self.lost_step >= answered_step:
            return [f'{self.topic} (none for step {self.lost_step} within {timeout:g} s: not answered; '
                    f'{matched(self.reader)})']
        return []
