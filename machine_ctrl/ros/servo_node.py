"""servo_node: the servo laws of any subset of axes (parameter `axes`: one node per axis,
one per stage, or all), answering every /joint_states step with /servo_commands.

Inputs per step k: the state (/joint_states), the reference row k of its axes (streamed
ahead in chunks on /reference, trajectory_msgs/JointTrajectory on the control grid),
for the axes a dual-stage coupling offsets (its fine axes; with mid-ranging its coarse axes
too: MachineConfig.offset_axes) the offsets of step k (/dual_stage/offsets) and, for
axes whose law closes the acceleration loop (pid with acceleration_gain > 0), the
accelerometer readings of step k (/accelerometers, sensor_msgs/Imu by the axis's link). An
input stream that has never delivered is waited for (reported on /diagnostics as
waiting_for); once it has, the node waits for a missing step up to `input_timeout` s (wall)
— so a lock-step run does not depend on message timing — and then: no reference row = hold
the last reference position at rest (underrun, counted and reported; one while the reference
moved breaks the stream: rows are refused until one at rest where the node holds,
model/reference.py ReferenceBuffer); no offsets or no reading = no answer (the law has no
setpoint or no feedback; counted as missing_offsets, missing_accelerations), so hw_sim
faults naming the axes after its command_timeout (README "Faults": the dual-stage node lost).
A repeated state stamp (hw_sim re-sends while waiting) is answered with the command already
computed, so no controller state is ever advanced twice.

Parameters (machine_ctrl/parameters.py SERVO): `axes` must name controlled axes of the
machine, each once; `belief`: files of the controllers' values (`machine-ctrl identify --out`)
the laws take over the machine config's (hw_sim, without the parameter, keeps the config's
plant: README "Truth and belief"). Live: `feedforward` (switched at the first step whose reference is at
rest on every axis of the node), `gains.<axis>.<gain>`, one per live gain of each axis's
law (control/law.py: a new parameter set, checked by the law, applied between two steps),
and `contour_control`, the machine's cross-coupled contour control
(control/contour_coupling.py: on from the next step, fading in from zero; off fades out),
offered by the node that holds every coupled axis (it then takes the whole /reference and
estimates the contour error of each step itself: a second node in the lock-step loop would
cost a hop per step). Their values in effect are in the node's /diagnostics status.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from sensor_msgs.msg import Imu, JointState

from machine_ctrl import contract, parameters
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.recording.cdr import JointStateData, JointStateEncoder
from machine_ctrl.control.contour_coupling import ContourCoupling, coupled_slots
from machine_ctrl.control.dual_stage import apply_offsets
from machine_ctrl.ros.local_bus import StepWriter
from machine_ctrl.ros.node_common import main_for, subscribe_joint_states, wall_timer
from machine_ctrl.ros.node_parameters import declare_parameters, gain_parameters, machine_parameter
from machine_ctrl.control.servo import ServoGroup
from machine_ctrl.ros.step_node import StepInput, StepNode


class ServoNode(StepNode):
    def __init__(self, name: str = 'servo', **kwargs):
        super().__init__(name, parameters.SERVO, **kwargs)
        self.machine = machine_parameter(self, belief=True)
        controlled = [a.name for a in self.machine.axes if a.control is not None]
        table = parameters.NodeParameters(parameters.SERVO.executable, parameters.SERVO.parameters,
                                          parameters.SERVO.checks + (axes_check(self.machine, controlled),),
                                          parameters.SERVO.sim_time)
        table = parameters.NodeParameters(table.executable, table.parameters,
                                          table.checks + (contour_check(self.machine),), table.sim_time)
        values = declare_parameters(self, table, {'axes': controlled}, names=('axes', 'feedforward', 'contour_control'),
                                    on_change={'feedforward': self.on_feedforward,
                                               'contour_control': self.on_contour_control})
        self.servo = ServoGroup(self.machine, values.axes, feedforward=values.feedforward)
        self.axes = self.servo.axis_names
        self.contour = None             # the cross-coupled contour control, if this node holds its axes
        self._contour_late_since = None  # wall time the contour block was first missing (None: here)
        self.contour_short = 0          # steps estimated without their whole reference block
        self.machine_axes = self.machine.axis_names     # kept: a property that builds the tuple each call
        if contour_axes(self.machine, self.axes):
            self.contour = ContourCoupling(self.machine, enabled=values.contour_control)
            self.contour_slots = coupled_slots(self.contour, self.axes)
            self.contour_ref_slots = [slot for slot, _ in self.contour_slots]
            self.own_columns = [self.machine_axes.index(a) for a in self.axes]
        self.declare_gains()
        offset = set(self.machine.offset_axes)
        self.offset_slots = [i for i, a in enumerate(self.axes) if a in offset]
        self.offset_names = [self.axes[i] for i in self.offset_slots]
        coupled = declare_parameters(self, parameters.SERVO, {'wait_for_offsets': bool(self.offset_slots)},
                                     names=('wait_for_offsets',)).wait_for_offsets
        self.wait_for_offsets = coupled and bool(self.offset_slots)
        self.offsets = StepInput(contract.DUAL_STAGE_OFFSETS.name)
        # the axes whose law reads its accelerometer, and their slots in the group
        self.accelerometer_axes = [self.machine.axis(a) for a in self.servo.uses_acceleration]
        self.acceleration_slots = [self.axes.index(a.name) for a in self.accelerometer_axes]
        self.accelerations = StepInput(contract.ACCELEROMETERS.name)

        self.make_buffer(self.axes)
        self.encoder = JointStateEncoder(self.axes)
        self.pub = StepWriter(self, JointState, contract.SERVO_COMMANDS.name, ros_io.STEP_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              ros_io.qos(contract.DIAGNOSTICS.qos))
        self.start_stepping(self.machine, self.machine_axes if self.contour else self.axes, self.pub,
                            self.ready, self.compute, self.streaming)
        if self.wait_for_offsets:
            self.offsets.reader = subscribe_joint_states(self, contract.DUAL_STAGE_OFFSETS.name, self.on_offsets,
                                                         lambda reason: self.rejections.add('offsets', reason))
        if self.accelerometer_axes:
            self.accelerations.reader = self.create_subscription(Imu, contract.ACCELEROMETERS.name,
                                                                 self.on_acceleration, ros_io.STEP_QOS)
        wall_timer(self, 1.0, self.publish_diagnostics)
        self.get_logger().info(f'ready: axes {" ".join(self.axes)}')

    def declare_gains(self) -> None:
        """One live parameter per live gain of each axis's law; the values given at start
        (overrides, a parameters file) are applied before the first step."""
        self.gains = gain_parameters(self.machine, self.axes)
        by_axis: dict[str, list] = {}
        for g in self.gains:
            by_axis.setdefault(g.axis, []).append(g)
        checks = tuple(parameters.Check(f'gains.{axis}', tuple(g.name for g in items), self._gains_test(axis, items),
                                        f'the conditions of the {axis} law') for axis, items in by_axis.items())
        table = parameters.NodeParameters(parameters.SERVO.executable, tuple(g.spec for g in self.gains), checks)
        hooks = {g.name: (lambda _value, axis=g.axis: self.retune(axis)) for g in self.gains}
        self.parameter_values = declare_parameters(self, table, on_change=hooks)       # kept current
        for axis in by_axis:
            self.retune(axis)

    def _gains_test(self, axis: str, items):
        law = self.servo.servo(axis).law

        def test(values):
            return law.retune_problem(dataclasses.replace(law.gains, **{g.gain: values[g.name] for g in items}))
        return test

    def retune(self, axis: str) -> None:
        """The law of `axis` takes the gains of the parameters (checked before they were set)."""
        law = self.servo.servo(axis).law
        self.servo.retune(axis, dataclasses.replace(
            law.gains, **{g.gain: self.parameter_values[g.name] for g in self.gains if g.axis == axis}))

    def on_feedforward(self, on: bool) -> None:
        self.servo.set_feedforward(on)

    def on_contour_control(self, on: bool) -> None:
        if self.contour is not None:          # else refused by contour_check
            self.contour.set_enabled(on)

    def on_reference(self, first_step: int, positions, velocities, accelerations) -> None:
        """With the contour control: every axis's rows, the node's own to the buffer."""
        if self.contour is None:
            return super().on_reference(first_step, positions, velocities, accelerations)
        rows = np.array([positions, velocities, accelerations], float)     # (3, steps, every axis)
        self.contour.add_reference(first_step, *rows)
        # the node's own columns picked in numpy (a list per row and field took ~0.4 ms a chunk)
        super().on_reference(first_step, *rows[:, :, self.own_columns].tolist())

    def on_offsets(self, msg: JointStateData) -> None:
        try:
            self.offsets.put(self.clock.step_at(msg.sec, msg.nanosec), ros_io.select(msg, 'position', self.offset_names))
        except ros_io.InvalidMessage as exc:
            self.rejections.add('offsets', str(exc))
            return
        self.responder.poke()

    def on_acceleration(self, msg: Imu) -> None:
        """One axis's reading of one step; the step's readings are complete with every axis's."""
        try:
            step = self.clock.step(msg.header.stamp)
            axis, value = ros_io.accelerometer_reading(msg, self.machine.accelerometer_axes)
        except ros_io.InvalidMessage as exc:
            self.rejections.add('accelerations', str(exc))
            return
        if all(a.name != axis for a in self.accelerometer_axes) or self.responder.has_answered(step):
            return                          # another node's axis, or a re-send of a step already answered
        readings = self.accelerations.pending.get(step, {})
        readings[axis] = value
        self.accelerations.put(step, readings)
        self.responder.poke()

    def _accelerations_of(self, step: int) -> bool:
        return len(self.accelerations.pending.get(step, ())) == len(self.accelerometer_axes)

    def streaming(self) -> bool:
        return self.buffer.started and (self.offsets.started or not self.wait_for_offsets) \
            and (self.accelerations.started or not self.accelerometer_axes)

    def ready(self, step: int) -> bool:
        return self.buffer.has(step) and (not self.wait_for_offsets or step in self.offsets.pending) \
            and (not self.accelerometer_axes or self._accelerations_of(step)) and self._contour_rows(step)

    def _contour_rows(self, step: int) -> bool:
        """Whether the contour control's estimate of `step` may go on: the reference block it
        reads is here (ContourCoupling.has_rows_for), or has been missing for input_timeout,
        timed from the first step that lacked it (in paced mode every step is new: a wait
        timed per step would never end). A lock-step run then does not depend on how far
        ahead the stream happens to be, unless it lags by longer than that."""
        if self.contour is None or self.contour.has_rows_for(step):
            self._contour_late_since = None
            return True
        now = time.monotonic()
        if self._contour_late_since is None:
            self._contour_late_since = now
        return now - self._contour_late_since > self.input_timeout

    def compute(self, step: int, msg: JointStateData) -> bytes | None:
        measured = self.positions(msg, self.axes, velocities=True)
        # every axis for the contour control, read before any input of the step is taken
        q = None if self.contour is None else self.positions(msg, self.machine_axes)
        if measured is None or (self.contour is not None and q is None):
            return None
        position, velocity = measured
        complete = not self.accelerometer_axes or self._accelerations_of(step)
        offsets, readings = self.offsets.take(step), self.accelerations.take(step)
        # the dual-stage node or hw_sim's accelerometer stream lost: no offsets or readings
        # within input_timeout. An axis without its offsets has no setpoint, an acceleration
        # loop without its reading no feedback: no answer, so hw_sim faults on the axes after
        # its command_timeout (README "Faults"); the inputs of this step sent again later (a
        # respawned dual_stage, hw_sim's re-send) are answered as usual
        if offsets is None and self.wait_for_offsets:
            self.offsets.miss(step)
            return None
        if not complete:
            self.accelerations.miss(step)
            return None
        ref_pos, ref_vel, ref_acc, _ = self.buffer.take(step, position)
        if offsets is not None:
            ref_pos = apply_offsets(ref_pos, self.offset_slots, offsets)
        # while the stream is broken (ReferenceBuffer) the rows the contour control reads may be
        # the refused ones: it is not stepped, and corrects nothing
        if self.contour is not None and self.buffer.broken_step is None:
            if not self.contour.has_rows_for(step):
                self.contour_short += 1          # estimated from fewer rows than its block
            corrections = self.contour.step(step, q).corrections
            ref_pos = apply_offsets(ref_pos, self.contour_ref_slots, [corrections[k] for _, k in self.contour_slots])
        acceleration = None
        if readings is not None:
            acceleration = [0.0] * len(self.axes)
            for slot, axis in zip(self.acceleration_slots, self.accelerometer_axes):
                acceleration[slot] = readings[axis.name]
        commands = self.servo.step(ref_pos, ref_vel, ref_acc, position, velocity, acceleration)
        return self.encoder.encode(msg.sec, msg.nanosec, effort=commands)

    def missing_inputs(self) -> list[str]:
        missing = []
        for waited, stream in ((self.wait_for_offsets, self.offsets), (bool(self.accelerometer_axes), self.accelerations)):
            if waited:
                missing += stream.waiting_text(self.responder.answered_step, self.input_timeout)
        return missing

    def publish_diagnostics(self) -> None:
        problems = self.reference_problems() or self.offsets.missing or self.accelerations.missing or \
            self.rejections.count
        step = self.responder.answered_step
        requested = self.servo.feedforward_requested
        values = {'axes': ' '.join(self.axes), 'answered_step': step, 'waiting_for': self.waiting_for(),
                  **self.reference_values(),
                  'missing_offsets': self.offsets.missing, 'missing_accelerations': self.accelerations.missing,
                  'rejected_messages': self.rejections.count,
                  'last_rejection': self.rejections.last, 'feedforward': self.servo.feedforward,
                  'feedforward_requested': '' if requested is None else requested,
                  **self.contour_values(),
                  **{g.name: getattr(self.servo.servo(g.axis).law.gains, g.gain) for g in self.gains}}
        self.pub_diag.publish(ros_io.diagnostics(
            self.clock.stamp(step), self.get_name(), DiagnosticStatus.WARN if problems else DiagnosticStatus.OK,
            self.problem_text(), values))

    def contour_values(self) -> dict:
        """The contour control's state for /diagnostics (nothing when the node has none)."""
        if self.contour is None:
            return {}
        return {'contour_control': self.contour.enabled, 'contour_control_status': self.contour.last.status.value,
                'contour_reference_short_steps': self.contour_short,
                'contour_control_reason': self.contour.last.reason,
                **{f'contour_invalid_{k}_steps': v for k, v in self.contour.invalid_steps.items()}}

    def problem_text(self) -> str:
        """The status message: what went wrong so far, or 'ok'."""
        problems = self.reference_problems() + [f'{count} {what}' for count, what in (
            (self.offsets.missing, 'steps without offsets'),
            (self.accelerations.missing, 'steps without accelerometer readings'),
            (self.rejections.count, 'rejected messages')) if count]
        return '; '.join(problems) or 'ok'


def contour_axes(machine, axes) -> bool:
    """Whether a node of `axes` holds every axis of the machine's contour control."""
    return machine.contour_control is not None and set(machine.contour_control.axes) <= set(axes)


def contour_check(machine) -> parameters.Check:
    """`contour_control` true only where the machine has one and the node holds its axes."""
    def test(values):
        if not values['contour_control'] or contour_axes(machine, values['axes']):
            return None
        if machine.contour_control is None:
            return f'{machine.name} has no contour_control section in its machine config'
        return (f'the node must hold every coupled axis ({" ".join(machine.contour_control.axes)}); '
                f'it has {" ".join(values["axes"])}')
    return parameters.Check('contour_control', ('axes', 'contour_control'), test, '')


def axes_check(machine, controlled) -> parameters.Check:
    """`axes`: controlled axes of `machine`, each once, at least one."""
    def test(values):
        axes = values['axes']
        unknown = [a for a in axes if a not in controlled]
        repeated = sorted({a for a in axes if axes.count(a) > 1})
        if not axes or unknown or repeated:
            what = (f'unknown {", ".join(map(repr, unknown))}' if unknown else
                    f'repeated {", ".join(repeated)}' if repeated else 'none')
            return f'must name controlled axes of {machine.name} ({", ".join(controlled)}), each once; {what}'
        return None
    return parameters.Check('axes', ('axes',), test, '')     # the text: the table's constraint


main = main_for(ServoNode)

if __name__ == '__main__':
    raise SystemExit(main())
