"""dual_stage_node: per step k, the fine-stage reference offsets of the dual-stage coupling
(thesis section 4.4; a Cartesian coupling through the kinematics, control/dual_stage.py) from
the coarse tracking errors, on /dual_stage/offsets
(sensor_msgs/JointState: name = the fine axes, then with mid-ranging the coarse axes;
position = offsets in m or rad; stamp = step k).
Inputs: /joint_states and the reference stream /reference (every axis of the machine; a chunk
without one is refused), and on a machine
whose Cartesian coupling has a tracker the tracker's reading of each step (/hw_sim/tracker,
geometry_msgs/PointStamped in the workpiece frame). Waits for a reference stream that never
started; once it has, waits up to `input_timeout` s (wall) for a missing row, then holds (see
servo_node). A step whose tracker reading does not come within `input_timeout` is not
answered (counted as missing_tracker): the fine axes have no setpoint, so hw_sim faults
naming them after its command_timeout, as for a lost dual_stage.
The live parameter `dual_stage` switches the coupling from the next step; while off the
offsets are zero. The service /dual_stage/enable (std_srvs/SetBool) sets that parameter, so
parameter, service and the `dual_stage` value of the /diagnostics status always agree.
Saturation at the fine stroke is counted and reported on /diagnostics.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import JointState
from rclpy.parameter import Parameter
from std_srvs.srv import SetBool

from machine_ctrl import contract, parameters
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.recording.cdr import JointStateData, JointStateEncoder
from machine_ctrl.control.dual_stage import DualStageCoupling
from machine_ctrl.ros.local_bus import StepWriter
from machine_ctrl.ros.node_common import main_for, wall_timer
from machine_ctrl.ros.node_parameters import declare_parameters, machine_parameter
from machine_ctrl.ros.step_node import StepInput, StepNode


class DualStageNode(StepNode):
    def __init__(self, name: str = 'dual_stage', **kwargs):
        super().__init__(name, parameters.DUAL_STAGE, **kwargs)
        self.machine = machine_parameter(self)
        if not self.machine.fine_axes:
            self.get_logger().fatal(f'{self.machine.name}: the machine config has no dual-stage coupling '
                                    f'(dual_stage pairs or cartesian_dual_stage)')
            raise SystemExit(2)
        dual_stage = declare_parameters(self, parameters.DUAL_STAGE,
                                        on_change={'dual_stage': self.on_dual_stage}).dual_stage
        self.coupling = DualStageCoupling(self.machine, dual_stage=dual_stage)
        self.axes = self.machine.axis_names
        self.make_buffer(self.axes)
        self.encoder = JointStateEncoder(self.coupling.offset_axes)
        self.pub = StepWriter(self, JointState, contract.DUAL_STAGE_OFFSETS.name, ros_io.STEP_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              ros_io.qos(contract.DIAGNOSTICS.qos))
        self.tracker = StepInput(contract.TRACKER.name)
        if self.coupling.uses_tracker:
            self.tracker.reader = self.create_subscription(PointStamped, contract.TRACKER.name, self.on_tracker,
                                                           ros_io.STEP_QOS)
        self.start_stepping(self.machine, self.axes, self.pub, self.ready, self.compute, streaming=self.streaming)
        self.create_service(SetBool, contract.DUAL_STAGE_ENABLE.name, self.on_enable)
        wall_timer(self, 1.0, self.publish_diagnostics)
        self.get_logger().info(f'ready: offsets of {" ".join(self.coupling.offset_axes)}')

    def on_dual_stage(self, on: bool) -> None:
        self.coupling.enabled = on

    def on_enable(self, request, response):
        """The service sets the parameter (one switch, whichever way it is used)."""
        (result,) = self.set_parameters([Parameter('dual_stage', value=bool(request.data))])
        response.success = result.successful
        response.message = (f'dual-stage coupling {"on" if request.data else "off"}' if result.successful
                            else result.reason)
        return response

    def on_tracker(self, msg: PointStamped) -> None:
        try:
            step = self.clock.step(msg.header.stamp)
            reading = ros_io.tracker_reading(msg, self.machine.workpiece_frame)
        except ros_io.InvalidMessage as exc:
            self.rejections.add('tracker', str(exc))
            return
        if not self.responder.has_answered(step):       # else a re-send of a step already answered
            self.tracker.put(step, reading)
            self.responder.poke()

    def streaming(self) -> bool:
        return self.buffer.started and (self.tracker.started or not self.coupling.uses_tracker)

    def ready(self, step: int) -> bool:
        return self.buffer.has(step) and (not self.coupling.uses_tracker or step in self.tracker.pending)

    def compute(self, step: int, msg: JointStateData) -> bytes | None:
        position = self.positions(msg, self.axes)
        if position is None:
            return None
        tracker = self.tracker.take(step)
        if tracker is None and self.coupling.uses_tracker:
            self.tracker.miss(step)
            return None
        ref_pos, _, _, _ = self.buffer.take(step, position)
        result = self.coupling.step(ref_pos, position, tracker)
        return self.encoder.encode(msg.sec, msg.nanosec, position=result.offsets)

    def missing_inputs(self) -> list[str]:
        return self.tracker.waiting_text(self.responder.answered_step, self.input_timeout) \
            if self.coupling.uses_tracker else []

    def publish_diagnostics(self) -> None:
        problems = self.reference_problems()
        warn = problems or self.rejections.count or self.coupling.saturation_count or self.tracker.missing
        step = self.responder.answered_step
        values = {'dual_stage': self.coupling.enabled, 'answered_step': step, 'waiting_for': self.waiting_for(),
                  'fine_stroke_saturations': self.coupling.saturation_count, 'missing_tracker': self.tracker.missing,
                  **self.reference_values(), 'rejected_messages': self.rejections.count,
                  'last_rejection': self.rejections.last}
        self.pub_diag.publish(ros_io.diagnostics(
            self.clock.stamp(step), 'dual_stage', DiagnosticStatus.WARN if warn else DiagnosticStatus.OK,
            '; '.join([f'coupling {"on" if self.coupling.enabled else "off"}', *problems]), values))


main = main_for(DualStageNode)

if __name__ == '__main__':
    raise SystemExit(main())
