"""view_node: the running graph in Foxglove (issue [7/8], part 3). A Foxglove WebSocket
server (foxglove-sdk) on `host`:`port`, fed by machine_ctrl/view/live_view.py with what this
node reads (raw CDR, not decoded here): joint states, servo commands and the contour error
magnitudes (per-step streams: the newest message of each taken `sample_rate` times a wall
second), reference chunks, goal status, trajectory status, diagnostics and the URDF, plus
the view's own /view/tracking_error and /view/scene (commanded path and measured tool-tip
trace in 3D).

Open it in Foxglove: "Open connection", ws://HOST:PORT, then import the machine's layout
config/foxglove/<machine>.json (machine_ctrl/view/layout.py; README "Live view"). What the
view cannot read (a state without the machine's axes: the view started for another
machine) is warned (throttled) and counted on /diagnostics (1 Hz: forwarded, taken, refused,
the last refusal, and the samples taken: at most VIEW_STEP_QOS.depth messages of a stream
each). The per-step streams are read best effort (contract.VIEW_STEP_QOS): a
slow view loses messages, it never holds up a writer; the latched ones as a late joiner
gets them. The server sends to clients from its own threads
(Rust), so a slow client does not hold up this node either.
"""
from __future__ import annotations

import foxglove
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node

from machine_ctrl import contract, parameters
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.ros.node_common import main_for, rejections, wall_timer
from machine_ctrl.ros.node_parameters import declare_parameters, machine_parameter
from machine_ctrl.ros.messages import message_class
from machine_ctrl.view.live_view import SessionView, ViewConfig

# What the view reads, and how. Of the per-step streams only those the layout plots and
# the commands: Fast DDS still delivers every message of a stream into the view's reader,
# at the graph's rate, before the sampling leaves most of them (bench/view_cost.py); the
# dual-stage offsets and the contour error vectors are left to the bag.
VIEWED = ((contract.JOINT_STATES, contract.VIEW_STEP_QOS), (contract.SERVO_COMMANDS, contract.VIEW_STEP_QOS),
          (contract.CONTOUR_TOOL_TIP_MAGNITUDE, contract.VIEW_STEP_QOS),
          (contract.CONTOUR_ORIENTATION_MAGNITUDE, contract.VIEW_STEP_QOS),
          (contract.REFERENCE, contract.REFERENCE_QOS), (contract.GOAL_STATUS, contract.LATCHED_READER_QOS),
          (contract.TRAJECTORY_STATUS, contract.LATCHED_READER_QOS),
          (contract.DIAGNOSTICS, contract.DIAGNOSTICS_READER_QOS),
          (contract.ROBOT_DESCRIPTION, contract.LATCHED_READER_QOS))


class ViewNode(Node):
    def __init__(self, name: str = 'view', **kwargs):
        super().__init__(name, **kwargs)
        self.machine = machine_parameter(self)
        values = declare_parameters(self, parameters.VIEW)
        self.foxglove_context = foxglove.Context()
        self.rejections = rejections(self)         # what the view could not read, warned (throttled)
        self.view = SessionView(self.machine, self.foxglove_context, ViewConfig(), self.get_namespace(), sampled=True,
                                refused=self.rejections.add)
        try:
            self.server = foxglove.start_server(name=f'machine_ctrl {self.machine.name}', host=values.host,
                                                port=values.port, context=self.foxglove_context)
        except Exception as exc:  # noqa: BLE001 - foxglove raises its own error types; the reason is what matters
            self.get_logger().fatal(f'cannot start the Foxglove server on {values.host}:{values.port}: {exc}')
            raise SystemExit(1) from None
        self.server_address = f'{values.host}:{self.server.port}'
        # The per-step streams are read by a node of their own that no executor spins: their
        # newest messages wait in its readers (contract.VIEW_STEP_QOS) until the sampling timer
        # takes them, so the messages in between cost this process nothing.
        self.sampler = Node(f'{name}_sampler', namespace=self.get_namespace(), context=self.context,
                            use_global_arguments=False, enable_rosout=False, start_parameter_services=False)
        self.sampled = []
        self.samples = 0                            # sampling timer ticks so far
        for topic, qos in VIEWED:
            name_, type_name = self.resolve_topic_name(topic.name), topic.type
            if qos == contract.VIEW_STEP_QOS:
                self.sampled.append((self.sampler.create_subscription(
                    message_class(type_name), topic.name, lambda _data: None, ros_io.qos(qos), raw=True),
                    name_, type_name))
            else:
                self.create_subscription(message_class(type_name), topic.name,
                                         lambda data, n=name_, t=type_name: self.view.take(n, t, data),
                                         ros_io.qos(qos), raw=True)
        wall_timer(self, 1.0 / values.sample_rate, self.sample)
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              ros_io.qos(contract.DIAGNOSTICS.qos))
        wall_timer(self, 1.0, self.publish_status)
        self.get_logger().info(f'ready: Foxglove WebSocket server on ws://{self.server_address} '
                               f'(layout: config/foxglove/{self.machine.name}.json)')

    def sample(self) -> None:
        """What each per-step stream's reader holds (its newest messages), oldest first."""
        self.samples += 1
        for subscription, name, type_name in self.sampled:
            with subscription.handle:
                for _ in range(contract.VIEW_STEP_QOS.depth):
                    taken = subscription.handle.take_message(subscription.msg_type, True)
                    if taken is None:
                        break
                    self.view.take(name, type_name, taken[0])

    def publish_status(self) -> None:
        """1 Hz on /diagnostics: messages forwarded and refused, the last refusal, samples taken."""
        view, refused = self.view, self.rejections
        level = DiagnosticStatus.WARN if refused.count else DiagnosticStatus.OK
        values = {'forwarded': sum(view.forwarded.values()), 'taken': sum(view.counts.values()),
                  'refused': refused.count, 'last_refusal': refused.last, 'samples': self.samples}
        self.pub_diag.publish(ros_io.diagnostics(self.get_clock().now().to_msg(), self.get_name(), level,
                                                 f'serving ws://{self.server_address}', values))

    def destroy_node(self):
        self.server.stop()
        self.sampler.destroy_node()
        return super().destroy_node()


main = main_for(ViewNode)

if __name__ == '__main__':
    raise SystemExit(main())
