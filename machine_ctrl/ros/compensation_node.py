"""compensation_node: geometric error compensation of the reference stream (Yuen thesis,
seed 000_d9dd5f6a818770e4.txt, Algorithm 2) between the trajectory source and the servos.

Subscribes `input_topic` (default /trajectory/reference) and publishes every chunk, corrected
(core: compensation.stream.CompensationStream), on `output_topic` (default /reference), same
first step and format (ros_io.trajectory_chunk; trajectory_msgs/JointTrajectory, SI units,
all machine axes, transient-local like every reference stream).
Parameters: `machine`, `model` (required: error model YAML, e.g. from machine-ctrl
fit-errors --out), `enabled` (live: on/off from the next chunk, ramped, see stream.py),
`input_topic`, `output_topic`. The service /compensation/enable (std_srvs/SetBool) sets
`enabled`, so parameter, service and the status agree. A malformed chunk is refused (reason on /diagnostics and the log), nothing is
forwarded for it and the node keeps running. /diagnostics (1 Hz wall): enabled, chunks, the
writers its input reader is matched with (none: the trajectory node is gone or not yet
discovered), refused chunks, rows stopped by the iteration cap, largest predicted residual. While it runs
it publishes compensation/ready (std_msgs/Bool, latched, with a liveliness lease), which the
trajectory node watches.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Bool
from std_srvs.srv import SetBool
from trajectory_msgs.msg import JointTrajectory

from compensation.compensate import Compensator
from compensation.error_map import load_error_map
from compensation.stream import CompensationStream
from machine_ctrl import contract, parameters
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.model.errors import ConfigError
from machine_ctrl.ros.node_common import main_for, qos, rejections, subscribe_reference, wall_timer
from machine_ctrl.ros.node_parameters import declare_parameters, machine_parameter


class CompensationNode(Node):
    def __init__(self, name: str = 'compensation', **kwargs):
        super().__init__(name, **kwargs)
        self.machine = machine_parameter(self)
        values = declare_parameters(self, parameters.COMPENSATION, on_change={'enabled': self.on_enabled})
        model, enabled, input_topic, output_topic = values.model, values.enabled, values.input_topic, values.output_topic
        try:
            compensator = Compensator.from_map(self.machine, load_error_map(model, self.machine.axis_names))
        except ConfigError as exc:
            self.get_logger().fatal(str(exc))
            raise SystemExit(2) from None
        self.stream = CompensationStream(compensator, self.machine.control_period, enabled)
        self.clock = ros_io.StepClock.of(self.machine)
        self.rejections = rejections(self)
        self.pub = self.create_publisher(JointTrajectory, output_topic, ros_io.REFERENCE_QOS)
        # latched, with a liveliness lease: the trajectory node learns that its reference no
        # longer reaches the servos when this node is gone (README "Faults")
        self.pub_ready = self.create_publisher(Bool, contract.COMPENSATION_READY.name,
                                               qos(contract.COMPENSATION_READY.qos))
        self.pub_ready.publish(Bool(data=True))
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              ros_io.qos(contract.DIAGNOSTICS.qos))
        self.sub = subscribe_reference(self, input_topic, self.clock, self.machine.axis_names, self.on_chunk,
                                       lambda reason: self.rejections.add('reference chunk', reason))
        self.create_service(SetBool, contract.COMPENSATION_ENABLE.name, self.on_enable)
        wall_timer(self, 1.0, self.publish_diagnostics)
        self.get_logger().info(f'ready: {input_topic} -> {output_topic}, model {model}, '
                               f'{"on" if enabled else "off"}')

    def on_chunk(self, first: int, positions, velocities, accelerations) -> None:
        q, v, a, _ = self.stream.transform(first, positions, velocities, accelerations)
        self.pub.publish(ros_io.trajectory_chunk(self.clock, first, self.machine.axis_names, q, v, a))

    def on_enabled(self, on: bool) -> None:
        self.stream.set_enabled(on)

    def on_enable(self, request, response):
        """The service sets the parameter (one switch, whichever way it is used)."""
        (result,) = self.set_parameters([Parameter('enabled', value=bool(request.data))])
        response.success = result.successful
        response.message = (f'compensation {"on" if request.data else "off"} from the next chunk (ramped)'
                            if result.successful else result.reason)
        return response

    def publish_diagnostics(self) -> None:
        s = self.stream
        problems = self.rejections.count or s.capped_rows
        values = {'enabled': s.enabled, 'chunks': s.chunks, 'input_writers': self.sub.get_publisher_count(),
                  'rejected_chunks': self.rejections.count,
                  'last_rejection': self.rejections.last, 'capped_rows': s.capped_rows,
                  'max_predicted_residual_m': s.max_residual}
        self.pub_diag.publish(ros_io.diagnostics(
            self.get_clock().now().to_msg(), 'compensation',
            DiagnosticStatus.WARN if problems else DiagnosticStatus.OK,
            f'compensation {"on" if s.enabled else "off"}', values))


main = main_for(CompensationNode)

if __name__ == '__main__':
    raise SystemExit(main())
