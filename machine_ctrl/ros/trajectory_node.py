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
* `/trajectory/program` (std_msgs/String): a G-code part program's text (the subset of
  trajectory/gcode.py; README "G-code"), for other robots and programs: read and planned
  whole (trajectory/part_program.py: each piece at its program feed, the `feed` parameter
  not used, exact stops between pieces), then run as a tool path (approach, hold, resume,
  stop, cancel and the feed override alike). A program that cannot be read or planned is
  refused (`program: planning failed: /trajectory/program:LINE: reason`), nothing moved;
  one with an M0 before its last motion too (on a topic nobody is there to go on after the stop; `machine-ctrl send`
  waits for Enter).
* `/trajectory/feed_override` (std_msgs/Float64): fraction 0..1 of the planned feed, for
  the motion under way and the next ones; a change is a smooth ramp (trajectory/stream.py)
  that keeps the motion on its path. Outside [0, 1] or not finite: refused.
* `/trajectory/hold` (std_srvs/Trigger): feed hold — on a tool path the override ramps to 0
  and the motion stops on its path; a point-to-point move (joint goal, home, a path's
  approach) is braked by a time-optimal jerk-limited stop — state holding, the program is
  kept; `/trajectory/resume` goes on (ramps back to the override setting, or moves on from
  where the move stopped to its waypoint), running; `/trajectory/stop` does the same as a
  hold and drops the rest of the motion (idle once at rest). Each acts `chunk_steps` after
  the newest /clock step (beyond any row the servos may have taken) and re-sends the stream
  from there; one that cannot act before the motion ends answers `success: false` with
  the reason (`too late: ...`).
* `/trajectory/home` (std_srvs/Trigger): move to the machine's home at rest.
* `/trajectory/freeform` (std_srvs/Trigger): the spindle-slaved freeform cut of the
  `freeform.*` parameters (surface, spindle speed, feed per revolution, start radius and
  angle, duration, lead-in/out time; trajectory/freeform.py, Ding Ch. 8): a jerk-limited entry to the cut's
  first state (spindle at speed, slide feeding, fast axis on the surface), the cut computed
  for every step from the commanded spindle angle and radius, a time-optimal stop. Planned in
  the planner process as a tool path is (the answer names the goal; a cut that cannot be
  made aborts it with the reason) and played as one (a hold ramps the feed override down
  along it).
* `/trajectory/cancel` (action_msgs/CancelGoal): cancel the active goal by id (zero id:
  whatever goal is active; a stamp: only a goal stamped at or before it), as a stop.

Goals (trajectory/goals.py): every path, program, joint goal, home and freeform cut gets an id (a UUID) and a
lifecycle — accepted, executing, canceling, succeeded, canceled, aborted (refused on
receipt too) — published latched on `/trajectory/goal_status`
(action_msgs/GoalStatusArray: the recent goals, GoalInfo.stamp = the request's
header.stamp; for home, a program and a freeform cut the sim time it came) and, with the reason, as a /diagnostics entry
named `<node>/goal` (values goal_id, status, status_code, reason, kind, label, stamp).
Hold, resume, stop and cancel act on the active goal and answer truthfully: a hold or stop
that cannot act before the motion ends is refused with the reason (trajectory/session.py).

Goals are accepted only while idle: one motion at a time, a goal during planning, a
motion, a hold or a fault is refused. After a motion the last position is held. The state
machine, goal bookkeeping and stream are ROS-free (trajectory/session.py); this node
converts messages to session calls and publishes what the session hands out.

Outputs: `/reference` chunks (parameter `output_topic`; trajectory_msgs/JointTrajectory on
the control grid, as the servos read them), `/trajectory/status` (diagnostic_msgs/DiagnosticStatus, latched:
message = state idle | planning | running | holding | fault; values: progress, motion,
last_rejection, goal_id and goal_status of the active goal, the `feed` parameter, ...),
`/trajectory/goal_status`, `/diagnostics`.

Timing: the node reads the sim step from /clock and keeps `lookahead_steps` rows streamed
ahead; a new motion starts at the first row not yet streamed, so it begins up to
`lookahead_steps` after the goal is accepted (plus the planning time) and never jumps.
Before the first /joint_states arrives nothing is streamed (the servos wait); then the
stream holds the measured position. When hw_sim reports a fault (/diagnostics, level
ERROR) the motion is dropped and the reference at the fault step is held; after hw_sim's
reset the state returns to idle. hw_sim's loss (the liveliness lease of its latched `ready`
runs out: killed, stopped, hung) is a fault too: the goal aborted naming hw_sim, the motion
stopped (trajectory/session.py). With compensation (`output_topic` trajectory/reference) the
loss of the compensation node (the lease of its latched compensation/ready) is treated alike:
goals refused, `reference_lost` in the status, nothing streamed; when it is back, the stream
is taken up again from the next /joint_states (where the servos held), then goals are
accepted. `/trajectory/goal_status` is offered with a liveliness
lease, so a client learns within it that this node is gone (README "Faults"); its own
process not run for longer than `stall_limit` (live, at most the lease) aborts the goal
under way (contract.STALL_LIMIT).
"""
from __future__ import annotations

import multiprocessing
import os
import time
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from action_msgs.msg import GoalInfo, GoalStatus, GoalStatusArray
from action_msgs.srv import CancelGoal
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.msg import Path
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64, String
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory
from unique_identifier_msgs.msg import UUID

from machine_ctrl import contract, parameters
from machine_ctrl.diagnostics import error_text
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.ros.node_common import main_for, qos, use_sim_time, wall_timer, watch_liveliness
from machine_ctrl.ros.node_parameters import declare_parameters, machine_parameter
from trajectory.freeform import Turning
from trajectory.goals import Goal, GoalState
from trajectory.session import (Answer, Session, plan_freeform, plan_path, plan_program_text, planner_process_init,
                                warm_planner)

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

    def goal(self, goal: Goal) -> None:
        self.node.publish_goal(goal)

    def log(self, text: str) -> None:
        self.node.get_logger().info(text)

    def warn(self, text: str) -> None:
        self.node.get_logger().warning(text, throttle_duration_sec=1.0)

    def want_state(self) -> None:
        self.node.read_state()


class TrajectoryNode(Node):
    def __init__(self, name: str = 'trajectory', **kwargs):
        super().__init__(name, **kwargs)
        use_sim_time(self)             # a clock refused goes to its log: rejected_goals counts goals
        self.machine = machine_parameter(self)
        # feed is live: a new value applies from the next tool path planned; stall_limit from
        # the next check
        freeform_names = [p.name for p in parameters.TRAJECTORY.parameters if p.name.startswith('freeform.')]
        values = declare_parameters(self, parameters.TRAJECTORY, on_change={
            'feed': lambda v: setattr(self, 'feed', v), 'stall_limit': lambda v: setattr(self.session, 'stall_limit', v),
            **{n: lambda _v: None for n in freeform_names}})
        self.parameter_values = values             # kept current: the freeform.* ones are read at the call
        self.feed, self.chunk_steps, self.lookahead = values.feed, values.chunk_steps, values.lookahead_steps
        output_topic = values.output_topic
        self.clock = ros_io.StepClock.of(self.machine)
        self.session = Session(self.machine, NodeOutputs(self), self.chunk_steps, self.lookahead, values.stall_limit)
        # Planning takes seconds of CPU; in a process of its own (spawned once, now) it
        # cannot hold up the streaming, as a thread would through the GIL.
        self.start_planner()
        self.planning: Future | None = None

        self.pub_reference = self.create_publisher(JointTrajectory, output_topic, ros_io.REFERENCE_QOS)
        self.pub_status = self.create_publisher(DiagnosticStatus, contract.TRAJECTORY_STATUS.name, LATCHED)
        # with a liveliness lease: a client following its goal learns that this node is gone
        self.pub_goals = self.create_publisher(GoalStatusArray, contract.GOAL_STATUS.name, qos(contract.GOAL_STATUS.qos))
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              ros_io.qos(contract.DIAGNOSTICS.qos))
        self.sub_state, self.state_reads = None, 0
        self.read_state()
        self.create_subscription(Clock, contract.CLOCK.name, self.on_clock, ros_io.qos(contract.CLOCK_READER_QOS))
        self.create_subscription(Path, contract.PATH.name, self.on_path, GOAL_QOS)
        self.create_subscription(JointTrajectory, contract.JOINT_GOAL.name, self.on_joint_goal, GOAL_QOS)
        self.sub_program = self.create_subscription(String, contract.PROGRAM.name, self.on_program, GOAL_QOS)
        self.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, self.on_diagnostics,
                                 ros_io.qos(contract.DIAGNOSTICS_READER_QOS))
        self.create_subscription(Float64, contract.FEED_OVERRIDE.name, self.on_feed_override, GOAL_QOS)
        # hw_sim's liveliness (the lease of its latched `ready`): lost is a fault (README "Faults")
        self.machine_lost_at: float | None = None
        watch_liveliness(self, Bool, contract.READY.name, contract.READY.qos, self.on_machine_alive)
        # with compensation, its liveliness (the lease of its latched `ready`): lost, the
        # reference no longer reaches the servos (README "Faults")
        self.chain_lost_at: float | None = None
        if output_topic == contract.TRAJECTORY_REFERENCE.name:
            watch_liveliness(self, Bool, contract.COMPENSATION_READY.name, contract.COMPENSATION_READY.qos,
                             self.on_chain_alive)
        self.create_service(Trigger, contract.HOLD.name, self.on_hold)
        self.create_service(Trigger, contract.RESUME.name, self.on_resume)
        self.create_service(Trigger, contract.STOP.name, self.on_stop)
        self.create_service(Trigger, contract.HOME.name, self.on_home)
        self.create_service(Trigger, contract.FREEFORM.name, self.on_freeform)
        self.create_service(CancelGoal, contract.CANCEL.name, self.on_cancel)
        wall_timer(self, 0.05, self.check_planning)
        wall_timer(self, 1.0, self.publish_status)
        self.publish_status()
        self.pub_goals.publish(GoalStatusArray())     # latched: no goal yet
        self.get_logger().info(f'ready: feed {self.feed * 1e3:g} mm/s; waiting for {contract.JOINT_STATES.name}')

    def start_planner(self) -> None:
        """The planner process: spawned and its imports done now, not at the first goal; its
        compiled resolution loaded next (a first goal waits for that, the node does not)."""
        self.planner = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context('spawn'),
                                           initializer=planner_process_init)
        self.planner_pid = self.planner.submit(os.getpid).result()
        self.planner.submit(warm_planner).add_done_callback(self.warmed)

    def warmed(self, future: Future) -> None:
        """(The pool's thread.) Say why the compiled resolution did not load ahead, if so:
        the first plan then loads, or compiles, it itself."""
        error = None if future.cancelled() else future.exception()
        if error is not None and not isinstance(error, BrokenProcessPool):     # not a stop
            self.get_logger().warning(f'the planner process did not load its compiled resolution ahead: '
                                      f'{error_text(error)}; the first plan will')

    def submit_plan(self, function, *args) -> None:
        """Hand `function(*args)` to the planner process. A pool whose worker died while it
        waited for work (BrokenProcessPool at the submit: e.g. after a plan a fault dropped)
        is restarted first, so that a goal is never lost to it."""
        try:
            self.planning = self.planner.submit(function, *args)
        except BrokenProcessPool:
            self.get_logger().warning('the planner process had died while idle: restarted')
            self.stop_planner()
            self.start_planner()
            self.planning = self.planner.submit(function, *args)

    def stop_planner(self) -> None:
        """Stop the planner process, abandoning a plan under way, and wait for its pool.

        The worker is terminated (a plan can take seconds), so the wait is short. The wait
        itself matters: a pool left to stop by itself (``shutdown(wait=False)``) races
        CPython 3.11's exit hook, which may write to the wake-up pipe the pool's thread has
        just closed (OSError EBADF and a traceback at exit; seen once in a loaded run).
        The worker is found among this process's live children, so a pid already reaped is
        never signalled."""
        for child in multiprocessing.active_children():
            if child.pid == self.planner_pid:
                child.terminate()
        self.planner.shutdown(wait=True, cancel_futures=True)

    # -- time ------------------------------------------------------------------------------
    def read_state(self) -> None:
        """Read one machine state from /joint_states (the first; again when the session asks:
        Outputs.want_state); between them the stream knows the state itself. A new reader
        each time (volatile): its first state is one sent after this call, never one queued
        before it (a read still waiting is replaced: after a stall of this node its queue
        holds the states of the stall's gap)."""
        if self.sub_state is not None:
            self.destroy_subscription(self.sub_state)
        self.state_reads += 1
        self.sub_state = self.create_subscription(JointState, contract.JOINT_STATES.name,
                                                  lambda msg, read=self.state_reads: self.on_state(msg, read),
                                                  ros_io.STEP_QOS)

    def on_state(self, msg: JointState, read: int) -> None:
        """The state asked for, to the session (Session.machine_state)."""
        if self.sub_state is None or read != self.state_reads:   # one the executor had taken from an ended read
            return
        try:
            step = self.clock.step(msg.header.stamp)
            position = ros_io.select(msg, 'position', self.machine.axis_names)
        except ros_io.InvalidMessage as exc:
            self.session.rejections.add('state', str(exc))
            return
        self.destroy_subscription(self.sub_state)
        self.sub_state = None
        self.session.machine_state(position, step)

    def on_clock(self, msg: Clock) -> None:
        try:
            step = self.clock.step(msg.clock)
        except ros_io.InvalidMessage:
            return
        now = time.monotonic()
        self.session.machine_heard(now)   # hw_sim's clock: a sign of life (Session.machine_heard)
        self.session.watch(now)           # a stall of this node first (README "Faults")
        self.session.tick(step)

    # -- goals -----------------------------------------------------------------------------
    @staticmethod
    def request_stamp(msg) -> tuple[int, int]:
        """The goal's stamp: the request's header.stamp as sent (it names the goal)."""
        return msg.header.stamp.sec, msg.header.stamp.nanosec

    def on_path(self, msg: Path) -> None:
        stamp, label = self.request_stamp(msg), f'path of {len(msg.poses)} points'
        if not self.session.may_accept('path', stamp, label):
            return
        try:
            cl = ros_io.path_to_cl(msg, self.machine.workpiece_frame)
        except ValueError as exc:
            self.session.refuse('path', str(exc), stamp, label)
            return
        self.submit_plan(plan_path, self.machine, cl, self.feed)
        self.session.planning(f'path of {len(cl)} points', stamp)
        self.session.touch(time.monotonic())         # reading a long path took this callback's time

    def on_program(self, msg: String) -> None:
        """A G-code program's text: read and planned in the planner process (plan_program_text),
        played as a tool path is. A String has no header: the goal is stamped with the sim
        time it came (as home)."""
        lines = len(msg.data.splitlines()) or 1
        stamp, label = self.clock.split(self.session.step), f'program of {lines} line{"s" if lines > 1 else ""}'
        if not self.session.may_accept('program', stamp, label):
            return
        self.submit_plan(plan_program_text, self.machine, msg.data, self.sub_program.topic_name)
        self.session.planning(label, stamp, kind='program')
        self.session.touch(time.monotonic())

    def on_machine_alive(self, alive: bool) -> None:
        self.machine_lost_at = None if alive else time.monotonic()
        self.session.machine_alive(alive, self.machine_lost_at)

    def on_chain_alive(self, alive: bool) -> None:
        self.chain_lost_at = None if alive else time.monotonic()
        self.session.chain_alive('compensation', alive, self.chain_lost_at)

    def check_planning(self) -> None:
        """Hand a finished plan to the session (approach from the held position, then the path)."""
        now = time.monotonic()
        self.session.watch(now)
        self.session.check_breaks(now)
        if self.machine_lost_at is not None:
            self.session.machine_alive(False, now)        # confirmed once hw_sim stays silent
        if self.chain_lost_at is not None:
            self.session.chain_alive('compensation', False, now)
        if self.planning is None or not self.planning.done():
            return
        future, self.planning = self.planning, None
        if not self.session.awaiting_plan:          # a fault came in meanwhile
            return
        try:
            reference, failure = future.result()
        except BrokenProcessPool:
            self.stop_planner()
            self.start_planner()
            reference, failure = None, 'the planner process died (restarted)'
        except Exception as exc:  # noqa: BLE001 - any planning error refuses the goal, the node goes on
            reference, failure = None, error_text(exc)
        self.session.path_planned(reference, failure)
        self.session.touch(time.monotonic())         # the approach planned in the callback

    def on_joint_goal(self, msg: JointTrajectory) -> None:
        times = [contract.seconds(p.time_from_start.sec, p.time_from_start.nanosec) for p in msg.points]
        self.session.accept_joint_goal(msg.joint_names, [list(p.positions) for p in msg.points], times,
                                       self.request_stamp(msg))
        self.session.touch(time.monotonic())         # planning the move took this callback's time

    def on_feed_override(self, msg: Float64) -> None:
        self.session.set_feed_override(msg.data)

    def answer(self, response, answer: Answer):
        response.success, response.message = answer.success, answer.message
        self.session.touch(time.monotonic())         # a stop or move planned in the callback
        return response

    def on_hold(self, request, response):
        return self.answer(response, self.session.hold())

    def on_resume(self, request, response):
        return self.answer(response, self.session.resume())

    def on_stop(self, request, response):
        return self.answer(response, self.session.stop())

    def on_home(self, request, response):
        return self.answer(response, self.session.home(self.clock.split(self.session.step)))

    def on_freeform(self, request, response):
        """Plan the cut of the freeform.* parameters in the planner process (as a tool path:
        the goal accepted now, aborted with the reason if it cannot be cut)."""
        v = self.parameter_values
        stamp, label = self.clock.split(self.session.step), f'freeform {v["freeform.surface"]}'
        if not self.session.may_accept('freeform', stamp, label):
            return self.answer(response, Answer(False, self.session.rejections.last))
        turning = Turning(v['freeform.spindle_speed'], v['freeform.feed_per_rev'], v['freeform.start_radius'],
                          v['freeform.duration'], v['freeform.start_angle'])
        here = self.session.stream.position(self.session.stream.next_step)
        self.submit_plan(plan_freeform, self.machine, v['freeform.surface'], turning, here, v['freeform.lead'])
        goal = self.session.planning(label, stamp, kind='freeform')
        return self.answer(response, Answer(True, f'planning {label} (goal {goal.uuid})'))

    def on_cancel(self, request, response):
        """action_msgs/CancelGoal on the active goal (trajectory.session.Session.cancel)."""
        info = request.goal_info
        goal_id = bytes(info.goal_id.uuid)
        code, goals = self.session.cancel(goal_id if any(goal_id) else None, (info.stamp.sec, info.stamp.nanosec))
        response.return_code = code
        response.goals_canceling = [self.goal_info(goal) for goal in goals]
        self.session.touch(time.monotonic())
        return response

    # -- faults ----------------------------------------------------------------------------
    def on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == 'compensation':
                self.session.chain_heard(time.monotonic())
            values = {kv.key: kv.value for kv in status.values}
            if values.get('reference_broken_step'):       # a servo's, the dual-stage node's (step_node)
                self.session.reference_broken(status.name, values['reference_broken_step'], time.monotonic())
            if status.name != 'hw_sim':
                continue
            self.session.machine_heard(time.monotonic())
            self.session.machine_status(status.level == DiagnosticStatus.ERROR,
                                        values.get('fault', status.message), values.get('step', ''),
                                        holds_step=values.get('mode') == 'lockstep')
        if not self.session.awaiting_plan:
            self.planning = None                     # a fault drops the plan under way

    # -- status ----------------------------------------------------------------------------
    def publish_status(self) -> None:
        session = self.session
        level = DiagnosticStatus.ERROR if session.faulted else DiagnosticStatus.OK
        stamp = self.clock.stamp(session.step)
        status = ros_io.diagnostics(stamp, self.get_name(), level, str(session.state),
                                    {**session.status_values(), 'feed': self.feed}).status[0]
        self.pub_status.publish(status)
        array = DiagnosticArray(status=[status])
        array.header.stamp = stamp
        self.pub_diag.publish(array)

    @staticmethod
    def goal_info(goal: Goal) -> GoalInfo:
        info = GoalInfo(goal_id=UUID(uuid=list(goal.id)))
        info.stamp.sec, info.stamp.nanosec = goal.stamp
        return info

    def publish_goal(self, goal: Goal) -> None:
        """A goal changed: its /diagnostics entry (with the reason), then the latched array
        of the recent goals."""
        level = DiagnosticStatus.WARN if goal.state == GoalState.ABORTED else DiagnosticStatus.OK
        message = f'goal {goal.state.text}: {goal.label}' + (f' ({goal.reason})' if goal.reason else '')
        self.pub_diag.publish(ros_io.diagnostics(self.clock.stamp(self.session.step), f'{self.get_name()}/goal',
                                                 level, message, goal.values()))
        self.pub_goals.publish(GoalStatusArray(status_list=[
            GoalStatus(goal_info=self.goal_info(g), status=int(g.state)) for g in self.session.goals.goals]))

    def destroy_node(self):
        self.stop_planner()
        return super().destroy_node()


main = main_for(TrajectoryNode)

if __name__ == '__main__':
    raise SystemExit(main())
