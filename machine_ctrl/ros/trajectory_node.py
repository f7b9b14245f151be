"""trajectory_node: accepts tool paths and joint goals, plans them, and streams the axis
references to the servos ahead of time (design.md "Time").

Inputs (every one validated; a refused goal moves nothing and its reason is published on
/trajectory/status and logged):
* `/trajectory/path` (nav_msgs/Path): cutter-location data in the workpiece frame
  (header.frame_id = the machine's workpiece frame; pose position = tool tip in m, pose
  z-axis = tool axis). Planned with `trajectory.planner.plan` at the `feed` parameter
  (m/s), preceded by a jerk-limited approach (Ruckig) from where the stream holds the
  machine to the path's start configuration.
* `/trajectory/joint_goal` (trajectory_msgs/JointTrajectory): axis goals (m, rad) for any
  subset of the axes (the others stay); several points are waypoints, each reached at
  rest; time_from_start all zero (time-optimal) or strictly increasing (earliest arrival).
* `/trajectory/feed_override` (std_msgs/Float64): fraction 0..1 of the planned feed, for
  the motion under way and the next ones; a change is a smooth ramp (trajectory/stream.py)
  that keeps the motion on its path. Outside [0, 1] or not finite: refused.
* `/trajectory/hold` (std_srvs/Trigger): feed hold, the override ramps to 0 and the motion
  stops on its path (state holding, the program is kept); `/trajectory/resume` ramps back
  to the override setting (running); `/trajectory/stop` ramps to 0 and drops the rest of
  the motion (idle once at rest). Each acts `chunk_steps` after the newest /clock step
  (beyond any row the servos may have taken) and re-sends the stream from there.
* `/trajectory/home` (std_srvs/Trigger): move to the machine's home at rest.

Goals are accepted only while idle: one motion at a time, a goal during planning, a
motion, a hold or a fault is refused. After a motion the last position is held. The state
machine, goal bookkeeping and stream are ROS-free (trajectory/session.py); this node
converts messages to session calls and publishes what the session hands out.

Outputs: `/reference` chunks (parameter `output_topic`; trajectory_msgs/JointTrajectory on
the control grid, as the servos read them), `/trajectory/status` (diagnostic_msgs/DiagnosticStatus, latched:
message = state idle | planning | running | holding | fault; values: progress, motion,
last_rejection, ...), `/diagnostics`.

Timing: the node reads the sim step from /clock and keeps `lookahead_steps` rows streamed
ahead; a new motion starts at the first row not yet streamed, so it begins up to
`lookahead_steps` after the goal is accepted (plus the planning time) and never jumps.
Before the first /joint_states arrives nothing is streamed (the servos wait); then the
stream holds the measured position. When hw_sim reports a fault (/diagnostics, level
ERROR) the motion is dropped and the reference at the fault step is held; after hw_sim's
reset the state returns to idle.
"""
from __future__ import annotations

import multiprocessing
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.msg import Path
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

from machine_ctrl import contract, parameters
from machine_ctrl.diagnostics import error_text
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.ros.node_common import main_for, use_sim_time, wall_timer
from machine_ctrl.ros.node_parameters import declare_parameters, machine_parameter
from trajectory.session import Answer, Session, plan_path

LATCHED = ros_io.qos(contract.LATCHED_QOS)
GOAL_QOS = ros_io.qos(contract.COMMAND_QOS)


class NodeOutputs:
    """trajectory.session.Outputs on the node's publishers and logger."""

    def __init__(self, node: TrajectoryNode):
        self.node = node

    def rows(self, first: int, positions, velocities, accelerations) -> None:
        node = self.node
        node.pub_reference.publish(ros_io.trajectory_chunk(node.clock, first, node.machine.axis_names,
                                                           positions, velocities, accelerations))

    def status(self) -> None:
        self.node.publish_status()

    def log(self, text: str) -> None:
        self.node.get_logger().info(text)

    def warn(self, text: str) -> None:
        self.node.get_logger().warning(text, throttle_duration_sec=1.0)


class TrajectoryNode(Node):
    def __init__(self, name: str = 'trajectory', **kwargs):
        super().__init__(name, **kwargs)
        use_sim_time(self)
        self.machine = machine_parameter(self)
        # feed is live: a new value applies from the next tool path planned
        values = declare_parameters(self, parameters.TRAJECTORY, on_change={'feed': lambda v: setattr(self, 'feed', v)})
        self.feed, self.chunk_steps, self.lookahead = values.feed, values.chunk_steps, values.lookahead_steps
        output_topic = values.output_topic
        self.clock = ros_io.StepClock.of(self.machine)
        self.session = Session(self.machine, NodeOutputs(self), self.chunk_steps, self.lookahead)
        # Planning takes seconds of CPU; in a process of its own (spawned once, now) it
        # cannot hold up the streaming, as a thread would through the GIL.
        self.planner = self.start_planner()
        self.planning: Future | None = None

        self.pub_reference = self.create_publisher(JointTrajectory, output_topic, ros_io.REFERENCE_QOS)
        self.pub_status = self.create_publisher(DiagnosticStatus, contract.TRAJECTORY_STATUS.name, LATCHED)
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              ros_io.qos(contract.DIAGNOSTICS.qos))
        self.sub_state = self.create_subscription(JointState, contract.JOINT_STATES.name, self.on_first_state,
                                                  ros_io.STEP_QOS)
        self.create_subscription(Clock, contract.CLOCK.name, self.on_clock, ros_io.qos(contract.CLOCK_READER_QOS))
        self.create_subscription(Path, contract.PATH.name, self.on_path, GOAL_QOS)
        self.create_subscription(JointTrajectory, contract.JOINT_GOAL.name, self.on_joint_goal, GOAL_QOS)
        self.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, self.on_diagnostics,
                                 ros_io.qos(contract.DIAGNOSTICS_READER_QOS))
        self.create_subscription(Float64, contract.FEED_OVERRIDE.name, self.on_feed_override, GOAL_QOS)
        self.create_service(Trigger, contract.HOLD.name, self.on_hold)
        self.create_service(Trigger, contract.RESUME.name, self.on_resume)
        self.create_service(Trigger, contract.STOP.name, self.on_stop)
        self.create_service(Trigger, contract.HOME.name, self.on_home)
        wall_timer(self, 0.05, self.check_planning)
        wall_timer(self, 1.0, self.publish_status)
        self.publish_status()
        self.get_logger().info(f'ready: feed {self.feed * 1e3:g} mm/s; waiting for {contract.JOINT_STATES.name}')

    @staticmethod
    def start_planner() -> ProcessPoolExecutor:
        pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context('spawn'))
        pool.submit(int).result()          # spawn and import now, not at the first goal
        return pool

    # -- time ------------------------------------------------------------------------------
    def on_first_state(self, msg: JointState) -> None:
        """Start streaming: hold the measured position from the step of the first state."""
        try:
            step = self.clock.step(msg.header.stamp)
            position = ros_io.select(msg, 'position', self.machine.axis_names)
        except ros_io.InvalidMessage as exc:
            self.session.rejections.add('state', str(exc))
            return
        self.destroy_subscription(self.sub_state)    # the stream knows the state from here on
        self.session.start_streaming(position, step)

    def on_clock(self, msg: Clock) -> None:
        try:
            step = self.clock.step(msg.clock)
        except ros_io.InvalidMessage:
            return
        self.session.tick(step)

    # -- goals -----------------------------------------------------------------------------
    def on_path(self, msg: Path) -> None:
        if not self.session.may_accept('path'):
            return
        try:
            cl = ros_io.path_to_cl(msg, self.machine.workpiece_frame)
        except ValueError as exc:
            self.session.refuse('path', str(exc))
            return
        self.planning = self.planner.submit(plan_path, self.machine, cl, self.feed)
        self.session.planning(f'path of {len(cl)} points')

    def check_planning(self) -> None:
        """Hand a finished plan to the session (approach from the held position, then the path)."""
        if self.planning is None or not self.planning.done():
            return
        future, self.planning = self.planning, None
        if not self.session.awaiting_plan:          # a fault came in meanwhile
            return
        try:
            reference, failure = future.result()
        except BrokenProcessPool:
            self.planner = self.start_planner()
            reference, failure = None, 'the planner process died (restarted)'
        except Exception as exc:  # noqa: BLE001 - any planning error refuses the goal, the node goes on
            reference, failure = None, error_text(exc)
        self.session.path_planned(reference, failure)

    def on_joint_goal(self, msg: JointTrajectory) -> None:
        times = [contract.seconds(p.time_from_start.sec, p.time_from_start.nanosec) for p in msg.points]
        self.session.accept_joint_goal(msg.joint_names, [list(p.positions) for p in msg.points], times)

    def on_feed_override(self, msg: Float64) -> None:
        self.session.set_feed_override(msg.data)

    @staticmethod
    def answer(response, answer: Answer):
        response.success, response.message = answer.success, answer.message
        return response

    def on_hold(self, request, response):
        return self.answer(response, self.session.hold())

    def on_resume(self, request, response):
        return self.answer(response, self.session.resume())

    def on_stop(self, request, response):
        return self.answer(response, self.session.stop())

    def on_home(self, request, response):
        return self.answer(response, self.session.home())

    # -- faults ----------------------------------------------------------------------------
    def on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name != 'hw_sim':
                continue
            values = {kv.key: kv.value for kv in status.values}
            self.session.machine_status(status.level == DiagnosticStatus.ERROR,
                                        values.get('fault', status.message), values.get('step', ''))
        if not self.session.awaiting_plan:
            self.planning = None                     # a fault drops the plan under way

    # -- status ----------------------------------------------------------------------------
    def publish_status(self) -> None:
        session = self.session
        level = DiagnosticStatus.ERROR if session.faulted else DiagnosticStatus.OK
        stamp = self.clock.stamp(session.step)
        status = ros_io.diagnostics(stamp, self.get_name(), level, str(session.state),
                                    session.status_values()).status[0]
        self.pub_status.publish(status)
        array = DiagnosticArray(status=[status])
        array.header.stamp = stamp
        self.pub_diag.publish(array)

    def destroy_node(self):
        self.planner.shutdown(wait=False, cancel_futures=True)
        return super().destroy_node()


main = main_for(TrajectoryNode)

if __name__ == '__main__':
    raise SystemExit(main())
