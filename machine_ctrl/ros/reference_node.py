"""reference_node: a simple reference source that plays a test contour (the trajectory node is
the general one).
Streams the references of a test contour (parameter `contour`: circle, square or hold) on
/reference in chunks of `chunk_steps` control steps, keeping `lookahead_steps` ahead of the
sim time it reads from /clock (like a CNC interpolator filling the servo buffer). After the
contour it holds the final position (streamed as rows at rest), so the servos never starve.
"""
from __future__ import annotations

from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from trajectory_msgs.msg import JointTrajectory

from machine_ctrl import contract, parameters
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.ros.node_common import main_for, use_sim_time
from machine_ctrl.ros.node_parameters import declare_parameters, machine_parameter
from trajectory.contours import contour_reference


class ReferenceNode(Node):
    def __init__(self, name: str = 'reference', **kwargs):
        super().__init__(name, **kwargs)
        use_sim_time(self)
        self.machine = machine_parameter(self)
        values = declare_parameters(self, parameters.REFERENCE)
        contour, self.chunk_steps, self.lookahead = values.contour, values.chunk_steps, values.lookahead_steps
        try:
            self.reference = contour_reference(self.machine, contour)
        except ValueError as exc:
            self.get_logger().fatal(f'parameter contour: {exc}')
            raise SystemExit(2) from None
        self.clock = ros_io.StepClock.of(self.machine)
        self.next_step = 0
        self.pub = self.create_publisher(JointTrajectory, contract.REFERENCE.name, ros_io.REFERENCE_QOS)
        self.create_subscription(Clock, contract.CLOCK.name, self.on_clock, ros_io.qos(contract.CLOCK_READER_QOS))
        self.fill(0)
        self.get_logger().info(f'ready: {contour}, {len(self.reference)} steps')

    def on_clock(self, msg: Clock) -> None:
        try:
            self.fill(self.clock.step(msg.clock))
        except ros_io.InvalidMessage:
            pass

    def fill(self, current_step: int) -> None:
        while self.next_step < current_step + self.lookahead:
            rows = [self.reference.row(k) for k in range(self.next_step, self.next_step + self.chunk_steps)]
            self.pub.publish(ros_io.trajectory_chunk(self.clock, self.next_step, self.machine.axis_names,
                                                     *zip(*rows)))
            self.next_step += self.chunk_steps


main = main_for(ReferenceNode)

if __name__ == '__main__':
    raise SystemExit(main())
