"""servo_node: the servo laws of any subset of axes (parameter `axes`: one node per axis,
one per stage, or all), answering every /joint_states step with /servo_commands.

Inputs per step k: the state (/joint_states), the reference row k of its axes (streamed
ahead in chunks on /reference, trajectory_msgs/JointTrajectory on the control grid) and,
for fine axes of a dual-stage pair, the offsets of step k (/dual_stage/offsets). An input
stream that has never delivered is waited for (reported on /diagnostics as waiting_for);
once it has, the node waits for a missing step up to `input_timeout` s (wall) — so a
lock-step run does not depend on message timing — and then: no reference row = hold the
last reference position at rest (underrun, counted and reported); no offsets = no answer
(a fine axis has no setpoint without them; counted as missing_offsets), so hw_sim faults
naming the fine axes after its command_timeout (README "Faults": the dual-stage node lost).
A repeated state stamp (hw_sim re-sends while waiting) is answered with the command already
computed, so no controller state is ever advanced twice.

Parameters (machine_ctrl/parameters.py SERVO): `axes` must name controlled axes of the
machine, each once. Live: `feedforward` (switched at the first step whose reference is at
rest on every axis of the node) and `gains.<axis>.<gain>`, one per live gain of each axis's
law (control/law.py: a new parameter set, checked by the law, applied between two steps).
Their values in effect are in the node's /diagnostics status.
"""
from __future__ import annotations

import dataclasses

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from sensor_msgs.msg import JointState

from machine_ctrl import contract, parameters
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.recording.cdr import JointStateData, JointStateEncoder
from machine_ctrl.control.dual_stage import apply_offsets
from machine_ctrl.ros.node_common import main_for, subscribe_joint_states, wall_timer
from machine_ctrl.ros.node_parameters import declare_parameters, gain_parameters, machine_parameter
from machine_ctrl.control.servo import ServoGroup
from machine_ctrl.ros.step_node import StepNode


class ServoNode(StepNode):
    def __init__(self, name: str = 'servo', **kwargs):
        super().__init__(name, parameters.SERVO, **kwargs)
        self.machine = machine_parameter(self)
        controlled = [a.name for a in self.machine.axes if a.control is not None]
        table = parameters.NodeParameters(parameters.SERVO.executable, parameters.SERVO.parameters,
                                          parameters.SERVO.checks + (axes_check(self.machine, controlled),),
                                          parameters.SERVO.sim_time)
        values = declare_parameters(self, table, {'axes': controlled}, names=('axes', 'feedforward'),
                                    on_change={'feedforward': self.on_feedforward})
        self.servo = ServoGroup(self.machine, values.axes, feedforward=values.feedforward)
        if self.servo.uses_acceleration:
            self.get_logger().fatal(f'axes {" ".join(self.servo.uses_acceleration)}: the acceleration loop '
                                    '(acceleration_gain > 0) needs the accelerometer reading, which the graph does '
                                    'not carry yet; run it offline (machine-ctrl experiment fts-accel)')
            raise SystemExit(2)
        self.axes = self.servo.axis_names
        self.declare_gains()
        fine = {p.fine for p in self.machine.dual_stage}
        self.fine_slots = [i for i, a in enumerate(self.axes) if a in fine]
        self.fine_names = [self.axes[i] for i in self.fine_slots]
        coupled = declare_parameters(self, parameters.SERVO, {'wait_for_offsets': bool(self.fine_slots)},
                                     names=('wait_for_offsets',)).wait_for_offsets
        self.wait_for_offsets = coupled and bool(self.fine_slots)
        self.offsets: dict[int, list[float]] = {}
        self.offsets_started = False
        self.missing_offsets = 0           # steps left unanswered for want of offsets
        self.offsets_lost_step = None      # the newest such step

        self.make_buffer(self.axes)
        self.encoder = JointStateEncoder(self.axes)
        self.pub = self.create_publisher(JointState, contract.SERVO_COMMANDS.name, ros_io.STEP_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              ros_io.qos(contract.DIAGNOSTICS.qos))
        self.start_stepping(self.machine, self.axes, self.pub, self.ready, self.compute, self.streaming)
        if self.wait_for_offsets:
            subscribe_joint_states(self, contract.DUAL_STAGE_OFFSETS.name, self.on_offsets,
                                   lambda reason: self.rejections.add('offsets', reason))
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

    def on_offsets(self, msg: JointStateData) -> None:
        try:
            self.offsets[self.clock.step_at(msg.sec, msg.nanosec)] = ros_io.select(msg, 'position', self.fine_names)
        except ros_io.InvalidMessage as exc:
            self.rejections.add('offsets', str(exc))
            return
        self.offsets_started = True
        self.responder.poke()

    def streaming(self) -> bool:
        return self.buffer.started and (self.offsets_started or not self.wait_for_offsets)

    def ready(self, step: int) -> bool:
        return self.buffer.has(step) and (not self.wait_for_offsets or step in self.offsets)

    def compute(self, step: int, msg: JointStateData) -> bytes | None:
        measured = self.positions(msg, self.axes, velocities=True)
        if measured is None:
            return None
        position, velocity = measured
        offsets = self.offsets.pop(step, None)
        for old in [s for s in self.offsets if s < step]:
            del self.offsets[old]
        if offsets is None and self.wait_for_offsets:
            # the dual-stage node lost (killed, stopped): no offsets within input_timeout. A
            # fine axis without its offsets has no setpoint: no answer, so hw_sim faults on
            # the fine axes after its command_timeout (README "Faults"); the offsets of a
            # respawned dual_stage for this step (hw_sim re-sends it) are answered as usual
            self.missing_offsets += 1
            self.offsets_lost_step = step
            return None
        ref_pos, ref_vel, ref_acc, _ = self.buffer.take(step, position)
        if offsets is not None:
            ref_pos = apply_offsets(ref_pos, self.fine_slots, offsets)
        commands = self.servo.step(ref_pos, ref_vel, ref_acc, position, velocity)
        return self.encoder.encode(msg.sec, msg.nanosec, effort=commands)

    def waiting_for(self) -> str:
        if not self.responder.waiting:
            return ''
        missing = [] if self.buffer.started else [f'{contract.REFERENCE.name} (never received)']
        if self.wait_for_offsets and not self.offsets_started:
            missing.append(f'{contract.DUAL_STAGE_OFFSETS.name} (never received)')
        elif self.wait_for_offsets and self.offsets_lost_step is not None and self.offsets_lost_step >= self.responder.answered_step:
            missing.append(f'{contract.DUAL_STAGE_OFFSETS.name} (none for step {self.offsets_lost_step} within '
                           f'{self.input_timeout:g} s: not answered)')
        return ', '.join(missing) or 'inputs of the current step'

    def publish_diagnostics(self) -> None:
        problems = self.buffer.underruns or self.missing_offsets or self.rejections.count
        step = self.responder.answered_step
        requested = self.servo.feedforward_requested
        values = {'axes': ' '.join(self.axes), 'answered_step': step, 'waiting_for': self.waiting_for(),
                  'reference_underruns': self.buffer.underruns, 'buffered_steps': len(self.buffer),
                  'missing_offsets': self.missing_offsets, 'rejected_messages': self.rejections.count,
                  'last_rejection': self.rejections.last, 'feedforward': self.servo.feedforward,
                  'feedforward_requested': '' if requested is None else requested,
                  **{g.name: getattr(self.servo.servo(g.axis).law.gains, g.gain) for g in self.gains}}
        self.pub_diag.publish(ros_io.diagnostics(
            self.clock.stamp(step), self.get_name(), DiagnosticStatus.WARN if problems else DiagnosticStatus.OK,
            'reference underrun' if self.buffer.underruns else 'ok', values))


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
