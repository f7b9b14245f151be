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
motion, a hold or a fault is refused. After a motion the last position is held.

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

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.msg import Path
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

from machine_ctrl.ros import messages as ros_io
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.ros.node_common import Rejections, declare, machine_parameter, main_for, use_sim_time, wall_timer
from machine_ctrl.model.reference import Reference
from trajectory import moves, toolpath
from trajectory.planner import DEFAULT_FEED, plan
from trajectory.stream import ReferenceStream

TOPIC_PATH = '/trajectory/path'
TOPIC_JOINT_GOAL = '/trajectory/joint_goal'
TOPIC_STATUS = '/trajectory/status'
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
GOAL_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


_kinematics: dict = {}


def plan_path(machine, cl: toolpath.CLData, feed: float) -> Reference:
    """The path's references, checked against the strokes (runs in the planner process)."""
    kinematics = _kinematics.get(machine.yaml_path) or _kinematics.setdefault(
        machine.yaml_path, Kinematics.from_config(machine))
    reference = plan(cl, machine, feed, kinematics=kinematics).reference
    problem = moves.stroke_violation(machine, reference)
    if problem:
        raise ValueError(f'planned path leaves a stroke: {problem}')
    return reference


class TrajectoryNode(Node):
    def __init__(self, name: str = 'trajectory', **kwargs):
        super().__init__(name, **kwargs)
        use_sim_time(self)
        self.machine = machine_parameter(self)
        self.feed = declare(self, 'feed', DEFAULT_FEED, 'process feed limit of tool paths, m/s')
        self.chunk_steps = max(1, declare(self, 'chunk_steps', 500, 'rows per /reference message'))
        self.lookahead = max(2 * self.chunk_steps, declare(self, 'lookahead_steps', 3000, 'rows kept ahead'))
        output_topic = declare(self, 'output_topic', ros_io.TOPIC_REFERENCE,
                               'reference chunks (/trajectory/reference when compensation sits between)')
        if not (isinstance(self.feed, (int, float)) and np.isfinite(self.feed) and self.feed > 0):
            self.get_logger().fatal(f'parameter feed: must be a positive speed in m/s, got {self.feed!r}')
            raise SystemExit(2)
        self.clock = ros_io.StepClock(self.machine.control_period)
        self.rejections = Rejections(self)
        self.stream: ReferenceStream | None = None
        self.state = 'idle'
        self.step = 0                                  # latest sim step seen on /clock
        # Planning takes seconds of CPU; in a process of its own (spawned once, now) it
        # cannot hold up the streaming, as a thread would through the GIL.
        self.planner = self.start_planner()
        self.planning: tuple[Future, str] | None = None
        self.fault = ''
        self.override_setting = 1.0
        self.limits = [a.limits for a in self.machine.axes]

        self.pub_reference = self.create_publisher(JointTrajectory, output_topic, ros_io.REFERENCE_QOS)
        self.pub_status = self.create_publisher(DiagnosticStatus, TOPIC_STATUS, LATCHED)
        self.pub_diag = self.create_publisher(DiagnosticArray, ros_io.TOPIC_DIAGNOSTICS, 10)
        self.sub_state = self.create_subscription(JointState, ros_io.TOPIC_JOINT_STATES, self.on_first_state,
                                                  ros_io.STEP_QOS)
        self.create_subscription(Clock, '/clock', self.on_clock, 10)
        self.create_subscription(Path, TOPIC_PATH, self.on_path, GOAL_QOS)
        self.create_subscription(JointTrajectory, TOPIC_JOINT_GOAL, self.on_joint_goal, GOAL_QOS)
        self.create_subscription(DiagnosticArray, ros_io.TOPIC_DIAGNOSTICS, self.on_diagnostics, 50)
        self.create_subscription(Float64, '/trajectory/feed_override', self.on_feed_override, GOAL_QOS)
        self.create_service(Trigger, '/trajectory/hold', self.on_hold)
        self.create_service(Trigger, '/trajectory/resume', self.on_resume)
        self.create_service(Trigger, '/trajectory/stop', self.on_stop)
        self.create_service(Trigger, '/trajectory/home', self.on_home)
        wall_timer(self, 0.05, self.check_planning)
        wall_timer(self, 1.0, self.publish_status)
        self.publish_status()
        self.get_logger().info(f'ready: feed {self.feed * 1e3:g} mm/s; waiting for /joint_states')

    @staticmethod
    def start_planner() -> ProcessPoolExecutor:
        pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context('spawn'))
        pool.submit(int).result()          # spawn and import now, not at the first goal
        return pool

    # -- time and streaming ----------------------------------------------------------------
    def on_first_state(self, msg: JointState) -> None:
        """Start streaming: hold the measured position from the step of the first state."""
        try:
            step = self.clock.step(msg.header.stamp)
            position = ros_io.select(msg, 'position', self.machine.axis_names)
        except ros_io.InvalidMessage as exc:
            self.rejections.add('state', str(exc))
            return
        self.destroy_subscription(self.sub_state)    # the stream knows the state from here on
        self.stream = ReferenceStream(self.machine.axis_names, self.machine.control_period, position, step)
        self.step = max(self.step, step)
        self.fill()
        self.publish_status()

    def on_clock(self, msg: Clock) -> None:
        try:
            self.step = max(self.step, self.clock.step(msg.clock))
        except ros_io.InvalidMessage:
            return
        self.fill()
        if self.state in ('running', 'holding') and not self.stream.busy(self.step):
            self.set_state('idle')

    def fill(self) -> None:
        if self.stream is None:
            return
        while self.stream.next_step < self.step + self.lookahead:
            first, p, v, a = self.stream.take(self.chunk_steps)
            self.pub_reference.publish(ros_io.trajectory_chunk(self.clock, first, self.machine.axis_names, p, v, a))

    # -- goals -----------------------------------------------------------------------------
    def refuse_goal(self, what: str, reason: str) -> None:
        self.rejections.add(what, reason)
        self.publish_status()

    def idle_or_refuse(self, what: str) -> bool:
        if self.stream is None:
            reason = 'the machine state is not known yet (no /joint_states)'
        elif self.state == 'fault':
            reason = f'machine is faulted ({self.fault}); reset hw_sim first'
        elif self.state != 'idle':
            reason = f'busy ({self.state}); one motion at a time'
        else:
            return True
        self.refuse_goal(what, reason)
        return False

    def on_path(self, msg: Path) -> None:
        if not self.idle_or_refuse('path'):
            return
        try:
            cl = ros_io.path_to_cl(msg, self.machine.workpiece_frame)
        except ValueError as exc:
            self.refuse_goal('path', str(exc))
            return
        self.planning = (self.planner.submit(plan_path, self.machine, cl, self.feed),
                         f'path of {len(cl)} points')
        self.set_state('planning')

    def on_joint_goal(self, msg: JointTrajectory) -> None:
        if not self.idle_or_refuse('joint goal'):
            return
        here = self.stream.position(self.stream.next_step)
        times = [p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec for p in msg.points]
        try:
            reference = moves.through_waypoints(self.machine, here, msg.joint_names,
                                                [list(p.positions) for p in msg.points], times)
        except ValueError as exc:
            self.refuse_goal('joint goal', str(exc))
            return
        self.begin(reference, f'joint goal ({len(msg.points)} points)')

    def check_planning(self) -> None:
        """Pick up a finished plan: approach from the held position, then the path."""
        if self.planning is None or not self.planning[0].done():
            return
        future, label = self.planning
        self.planning = None
        if self.state != 'planning':          # a fault came in meanwhile
            return
        try:
            path = future.result()
            here = self.stream.position(self.stream.next_step)
            approach = moves.move_to(self.machine, path.position[0], moves.AxisState.at_rest(here))
        except BrokenProcessPool:
            self.planner = self.start_planner()
            self.set_state('idle')
            self.refuse_goal('path', 'planning failed: the planner process died (restarted)')
            return
        except Exception as exc:  # noqa: BLE001 - any planning error refuses the goal, the node goes on
            reason = str(exc) if isinstance(exc, ValueError) else f'{type(exc).__name__}: {exc}'
            self.set_state('idle')
            self.refuse_goal('path', f'planning failed: {reason}')
            return
        self.begin(moves.concatenate([approach, path]), label)

    def begin(self, reference: Reference, label: str) -> None:
        self.stream.start(reference, label, self.limits, self.override_setting)
        self.get_logger().info(f'{label}: {len(reference)} steps from step {self.stream.motion.start}')
        self.set_state('running')
        self.fill()

    def change_feed(self, value: float, state: str, stop: bool = False) -> str:
        """Ramp the override of the motion under way, from beyond what the servos may have
        taken; re-send the stream from there."""
        begin = self.stream.set_override(value, self.step + self.chunk_steps, stop)
        self.set_state(state)
        self.fill()
        return f'feed {value:g} from step {begin}'

    def on_feed_override(self, msg: Float64) -> None:
        value = msg.data
        if not (np.isfinite(value) and 0.0 <= value <= 1.0):
            self.refuse_goal('feed override', f'{value!r} is not a fraction within [0, 1]')
            return
        self.override_setting = float(value)
        if self.state == 'running':
            self.change_feed(self.override_setting, 'running')
        self.publish_status()

    def on_hold(self, request, response):
        return self.answer(response, self.state == 'running', lambda: self.change_feed(0.0, 'holding'))

    def on_resume(self, request, response):
        return self.answer(response, self.state == 'holding' and not self.stream.motion.stop_when_still,
                           lambda: self.change_feed(self.override_setting, 'running'))

    def on_stop(self, request, response):
        return self.answer(response, self.state in ('running', 'holding'),
                           lambda: self.change_feed(0.0, 'holding', stop=True))

    def answer(self, response, allowed: bool, action):
        """Service answer: the action's message, or why it does not apply now."""
        if not allowed:
            response.success, response.message = False, f'not applicable while {self.state}'
            return response
        try:
            response.success, response.message = True, action()
        except ValueError as exc:
            response.success, response.message = False, str(exc)
        return response

    def on_home(self, request, response):
        if not self.idle_or_refuse('home'):
            response.success, response.message = False, self.rejections.last
            return response
        here = moves.AxisState.at_rest(self.stream.position(self.stream.next_step))
        self.begin(moves.home(self.machine, here), 'home')
        response.success, response.message = True, f'homing in {len(self.stream.motion.reference)} steps'
        return response

    # -- faults ----------------------------------------------------------------------------
    def on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name != 'hw_sim':
                continue
            values = {kv.key: kv.value for kv in status.values}
            if status.level == DiagnosticStatus.ERROR and self.state != 'fault':
                self.on_fault(values.get('fault', status.message), values.get('step', ''))
            elif status.level != DiagnosticStatus.ERROR and self.state == 'fault':
                self.fault = ''
                self.set_state('idle')

    def on_fault(self, reason: str, step_text: str) -> None:
        self.fault = reason
        self.planning = None
        if self.stream is not None and step_text.isdigit():
            self.stream.abort(int(step_text) + 1)   # hw_sim stopped at the fault step
            self.fill()
        self.set_state('fault')

    # -- status ----------------------------------------------------------------------------
    def set_state(self, state: str) -> None:
        if state != self.state:
            self.state = state
            self.get_logger().info(f'state: {state}')
        self.publish_status()

    def status(self) -> DiagnosticStatus:
        motion = self.stream.motion if self.stream is not None else None
        level = {'fault': DiagnosticStatus.ERROR}.get(self.state, DiagnosticStatus.OK)
        values = {'state': self.state, 'step': self.step,
                  'progress': f'{self.stream.progress(self.step):.4f}' if self.stream else '0',
                  'motion': motion.label if motion else '',
                  'motion_start_step': motion.start if motion else '',
                  'motion_end_step': motion.end if motion and motion.end is not None else '',
                  'streamed_to_step': self.stream.next_step if self.stream else '',
                  'feed_override': f'{self.stream.override(self.step):.4f}' if self.stream else '1',
                  'feed_override_setting': self.override_setting,
                  'fault': self.fault, 'rejected_goals': self.rejections.count,
                  'last_rejection': self.rejections.last}
        return ros_io.diagnostics(self.clock.stamp(self.step), self.get_name(), level, self.state,
                                  values).status[0]

    def publish_status(self) -> None:
        status = self.status()
        self.pub_status.publish(status)
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.clock.stamp(self.step)
        self.pub_diag.publish(array)

    def destroy_node(self):
        self.planner.shutdown(wait=False, cancel_futures=True)
        return super().destroy_node()


main = main_for(TrajectoryNode)

if __name__ == '__main__':
    raise SystemExit(main())
