"""contour_error_node: tool-tip and tool-orientation contour errors of every control step
(Sencer Eqs. 17-28, core in machine_ctrl/contour/estimation.py), for anyone (recorder, contouring
control of [6/7]).

Inputs: /reference (trajectory_msgs/JointTrajectory chunks on the control grid, all axes of
the machine), converted to the reference tool trajectory when a chunk arrives, and
/joint_states (the measured axes of step k). Per state of step k whose reference row is
there (states of steps already done — hw_sim's re-sends — are ignored):

    /contour_error/tool_tip               geometry_msgs/Vector3Stamped  m, frame `workpiece`
    /contour_error/tool_tip_magnitude     std_msgs/Float64              m
    /contour_error/orientation            geometry_msgs/Vector3Stamped  rad (small-angle vector), frame `workpiece`
    /contour_error/orientation_magnitude  std_msgs/Float64              rad

published in that order, stamp = the state's stamp. Parameters: `machine`, `estimator`
(basic | shifted | compensated). A state whose reference row has not arrived waits for it
(so start-up timing cannot change what is published); after MAX_SHIFT worth of steps
without it the oldest waiting state is given up (counted on /diagnostics). A refused
message is reported and the node keeps running.
"""
from __future__ import annotations

import math
from collections import deque

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Vector3Stamped
from rclpy.node import Node
from std_msgs.msg import Float64

from machine_ctrl import contract, parameters
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.recording.cdr import JointStateData
from machine_ctrl.contour.estimation import MAX_SHIFT, ContourEstimator, ToolTrajectory, tool_reference
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.ros.node_common import (main_for, rejections, subscribe_joint_states, subscribe_reference,
                                          use_sim_time, wall_timer)
from machine_ctrl.ros.node_parameters import declare_parameters, machine_parameter



class ContourErrorNode(Node):
    def __init__(self, name: str = 'contour_error', **kwargs):
        super().__init__(name, **kwargs)
        use_sim_time(self)
        self.machine = machine_parameter(self)
        method = declare_parameters(self, parameters.CONTOUR_ERROR).estimator
        self.kinematics = Kinematics.from_config(self.machine)
        try:
            self.estimator = ContourEstimator(self.kinematics, method)
        except ValueError as exc:
            self.get_logger().fatal(f'parameter estimator: {exc}')
            raise SystemExit(2) from None
        self.clock = ros_io.StepClock.of(self.machine)
        self.trajectory = ToolTrajectory(self.machine.control_period)
        self.history = int(math.ceil(MAX_SHIFT / self.machine.control_period)) + 2
        self.last_step = -1
        self.pending: deque = deque()      # states waiting for their reference row
        self.skipped = 0
        self.rejections = rejections(self)
        self.frame = self.machine.workpiece_frame
        self.pubs = [self.create_publisher(kind, topic, ros_io.STEP_QOS) for kind, topic in (
            (Vector3Stamped, contract.CONTOUR_TOOL_TIP.name), (Float64, contract.CONTOUR_TOOL_TIP_MAGNITUDE.name),
            (Vector3Stamped, contract.CONTOUR_ORIENTATION.name), (Float64, contract.CONTOUR_ORIENTATION_MAGNITUDE.name))]
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              ros_io.qos(contract.DIAGNOSTICS.qos))
        subscribe_reference(self, contract.REFERENCE.name, self.clock, self.machine.axis_names, self.on_reference,
                            lambda reason: self.rejections.add('reference', reason))
        subscribe_joint_states(self, contract.JOINT_STATES.name, self.on_state,
                               lambda reason: self.rejections.add('state', reason))
        wall_timer(self, 1.0, self.publish_diagnostics)
        self.get_logger().info(f'ready: {method} estimator')

    def on_reference(self, first: int, q, qd, qdd) -> None:
        self.trajectory.add(first, *tool_reference(self.kinematics, q, qd, qdd))
        self.process()

    def on_state(self, msg: JointStateData) -> None:
        try:
            step = self.clock.step_at(msg.sec, msg.nanosec)
            q = ros_io.select(msg, 'position', self.machine.axis_names)
        except ros_io.InvalidMessage as exc:
            self.rejections.add('state', str(exc))
            return
        if step <= self.last_step:
            return
        self.last_step = step
        self.pending.append((step, q))
        if len(self.pending) > self.history:       # no reference for that long: give the oldest up
            self.pending.popleft()
            self.skipped += 1
        self.process()

    def process(self) -> None:
        """Estimate the waiting states, in step order, as far as their reference rows are here."""
        while self.pending and self.trajectory.has(self.pending[0][0]):
            step, q = self.pending.popleft()
            self.trajectory.drop_before(step - self.history)
            estimate = self.estimator.update(self.trajectory, step, q)
            for pub, message in zip(self.pubs, self.messages(self.clock.stamp(step), estimate)):
                pub.publish(message)

    def messages(self, stamp, estimate):
        out = []
        for vector in (estimate.tool_tip.vector, estimate.orientation):
            msg = Vector3Stamped()
            msg.header.stamp, msg.header.frame_id = stamp, self.frame
            msg.vector.x, msg.vector.y, msg.vector.z = (float(v) for v in vector)
            out += [msg, Float64(data=math.sqrt(sum(v * v for v in vector)))]
        return out

    def publish_diagnostics(self) -> None:
        problems = self.skipped or self.rejections.count
        values = {'estimator': self.estimator.tip.method, 'last_step': self.last_step,
                  'skipped_steps': self.skipped, 'buffered_steps': len(self.trajectory),
                  'rejected_messages': self.rejections.count, 'last_rejection': self.rejections.last}
        self.pub_diag.publish(ros_io.diagnostics(
            self.clock.stamp(max(self.last_step, 0)), self.get_name(),
            DiagnosticStatus.WARN if problems else DiagnosticStatus.OK,
            'steps without reference' if self.skipped else 'ok', values))


main = main_for(ContourErrorNode)

if __name__ == '__main__':
    raise SystemExit(main())
