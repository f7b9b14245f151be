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
        use_sim_time(self)
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

    def make_buffer(self, axes) -> ReferenceBuffer:
        self.buffer = ReferenceBuffer(axes)
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
