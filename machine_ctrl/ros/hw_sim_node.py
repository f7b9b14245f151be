"""hw_sim_node: the simulated machine on the ROS graph (design.md "The node graph", "Time").

Publishes /clock (every `clock_decimation` steps), /joint_states (measured positions,
differentiated velocities, efforts = commands applied over the previous period; stamp =
sim time of the step), ground truth every `ground_truth_decimation` steps (default 10:
1 kHz on the micromill) on /hw_sim/ground_truth/joint_states and
/hw_sim/ground_truth/tool_pose (true tool tip in the workpiece frame, with the structure's
deflection under the cutting force on a machine with simulation.tool_compliance; no controller
subscribes to them; each is computed and published only while it has a subscriber, as the
true tool pose through the error map costs ~0.15 ms), /accelerometers (sensor_msgs/Imu, one
per step and accelerometer of the machine, before the step's state, while subscribed: the
reading of hw_sim.flexure.Accelerometer along the axis, frame_id the axis's URDF link),
/hw_sim/tracker (geometry_msgs/PointStamped, one per step before the state, while subscribed,
on a machine whose Cartesian coupling has a tracker: the coarse stage's tool tip as the
tracking system reads it, frame the workpiece) and /diagnostics (1 Hz wall, and at once on a fault). Per-step states go out and commands come in as CDR bytes
(machine_ctrl.recording.cdr; standard sensor_msgs/JointState on the wire). Subscribes
/servo_commands (sensor_msgs/JointState: name = axes, effort = commands, stamp = the stamp
of the state answered). Service /hw_sim/reset (std_srvs/Trigger) clears a fault.

For clients and tools, latched (transient local, depth 1): `ready` (std_msgs/Bool) false
at start, true once the graph has completed its first step (hw_sim.session: every axis
answered step 0 in lock-step mode, every axis commanded once when paced), so a client that
waits for it finds every node with its first state; `robot_description` (std_msgs/String)
the machine's URDF as its file says it, once at start: its movable joints are the axes, by
the names of /joint_states, so robot_state_publisher turns /joint_states into /tf and RViz
shows the machine, live or from a bag.

Modes (parameter `mode`) and faults are hw_sim.session's (ROS-free, unit-tested in
test/test_hw_sim_session.py), which decides when to advance, re-send, hold, refuse or fault; this
node converts the messages, passes each event in with the wall time and publishes what the
session says:
* lockstep (default): step k -> k+1 once every axis has its step-k command; while waiting,
  the state is re-sent every `republish_period` s (nodes answer a repeated stamp with the
  command they already computed). `min_subscribers` > 0 holds at step 0 until that many
  /joint_states subscribers are matched (a recorder that must see every step).
  `recorder_window` W > 0 (steps) is flow control for a recorder that reports on
  /recorder/progress (builtin_interfaces/Time: the stamp up to which every per-step stream is written):
  hw_sim does not advance from step k while k minus that step exceeds W, nor from step 0
  while the recorder reports step -1 (none written yet); a recorder that leaves the graph
  releases the hold. `wait_for_recorder` holds step 0 until a recorder has reported at
  all (bringup --record). Holding delays a run, it never changes it.
* paced: steps on the wall clock at `real_time_factor`, applying the latest command of
  each axis (zero-order hold) and counting missed deadlines, with the step latency and
  hw_sim's own tick lateness as percentiles on /diagnostics (hw_sim/pacing.py) — the
  contract a driver for real hardware implements.

Faults (machine stopped, the node keeps running and reporting): a non-finite command, a
stroke violation, a command missing for `command_timeout` s (lock-step: from step 1 on;
paced: an axis without any command that long once the graph is ready), hw_sim's own process
not run for that long (both modes).
Malformed commands and progress reports are refused with the reason on /diagnostics and
change nothing.
"""
from __future__ import annotations

import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PointStamped, PoseStamped
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger

from hw_sim.session import LockStepSession, PacedSession
from hw_sim.simulator import MachineSimulator
from machine_ctrl import contract, parameters
from machine_ctrl.model.numeric import all_finite
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.recording.cdr import JointStateData, JointStateEncoder, encode_time
from machine_ctrl.model.errors import ConfigError
from machine_ctrl.ros.local_bus import StepWriter
from machine_ctrl.ros.node_common import main_for, qos, subscribe_joint_states, wall_timer, watch_liveliness
from machine_ctrl.ros.node_parameters import declare_parameters, machine_parameter


class HwSimNode(Node):
    def __init__(self, name: str = 'hw_sim', **kwargs):
        super().__init__(name, **kwargs)
        self.machine = machine_parameter(self)
        axes = self.machine.axis_names
        values = declare_parameters(self, parameters.HW_SIM, {'initial_position': [float(v) for v in self.machine.home]})
        self.check_parameters(values.initial_position)
        self.clock = ros_io.StepClock.of(self.machine)
        try:
            self.sim = MachineSimulator(self.machine, initial_position=values.initial_position)
            self.sim.true_tool_pose()              # its error map read now: a bad one stops the node at once
        except ConfigError as exc:
            self.get_logger().fatal(str(exc))
            raise SystemExit(2) from None
        common = {'clock_decimation': values.clock_decimation, 'truth_decimation': values.ground_truth_decimation}
        if values.mode == 'lockstep':
            self.session = LockStepSession(self.sim, self.clock, self, command_timeout=values.command_timeout,
                                           republish_period=values.republish_period,
                                           min_subscribers=values.min_subscribers,
                                           recorder_window=values.recorder_window,
                                           wait_for_recorder=values.wait_for_recorder, **common)
        else:
            self.session = PacedSession(self.sim, self.clock, self, real_time_factor=values.real_time_factor,
                                        command_timeout=values.command_timeout, **common)
        self.encoder = JointStateEncoder(axes)

        # per-step traffic when clock_decimation is 1; deep like the states, so a recorder
        # that hw_sim lets fall recorder_window steps behind loses no /clock either
        self.pub_clock = self.create_publisher(Clock, contract.CLOCK.name, ros_io.STEP_QOS)
        self.pub_state = StepWriter(self, JointState, contract.JOINT_STATES.name, ros_io.STEP_QOS)
        # one sensor_msgs/Imu per accelerometer and step, while subscribed (a servo with the
        # acceleration loop, a recorder; a lock-step re-send of the state re-sends them too)
        self.accelerometer_axes = [(self.machine.axes.index(a), a) for a in self.machine.accelerometer_axes]
        self.pub_acceleration = (self.create_publisher(Imu, contract.ACCELEROMETERS.name, ros_io.STEP_QOS)
                                 if self.accelerometer_axes else None)
        # the tracker's reading of each step (a Cartesian coupling's dual_stage waits for it), while subscribed
        self.pub_tracker = (self.create_publisher(PointStamped, contract.TRACKER.name, ros_io.STEP_QOS)
                            if self.machine.tracker is not None else None)
        self.pub_true = self.create_publisher(JointState, contract.TRUE_JOINT_STATES.name, ros_io.STEP_QOS)
        self.pub_pose = self.create_publisher(PoseStamped, contract.TRUE_TOOL_POSE.name, ros_io.STEP_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              ros_io.qos(contract.DIAGNOSTICS.qos))
        # with a liveliness lease: the trajectory node learns from it that hw_sim is gone
        self.pub_ready = self.create_publisher(Bool, contract.READY.name, qos(contract.READY.qos))
        self.pub_description = self.create_publisher(String, contract.ROBOT_DESCRIPTION.name,
                                                     ros_io.qos(contract.ROBOT_DESCRIPTION.qos))
        self.pub_description.publish(String(data=self.machine.urdf_path.read_text()))
        self.ready_published = False
        self.pub_ready.publish(Bool(data=False))
        subscribe_joint_states(self, contract.SERVO_COMMANDS.name, self.on_command, self.refuse_command)
        self.sub_progress = (self.create_subscription(Time, contract.RECORDER_PROGRESS.name, self.on_progress,
                                                     ros_io.qos(contract.PROGRESS_QOS))
                             if values.recorder_window > 0 else None)
        # the recorder's liveliness (a second subscription: this one asks for the lease, which a
        # progress writer without one would not match): lost releases a hold within the lease
        self.sub_recorder_alive = (watch_liveliness(self, Time, contract.RECORDER_PROGRESS.name, contract.PROGRESS_QOS,
                                                    self.on_recorder_alive)
                                   if values.recorder_window > 0 else None)
        self.create_service(Trigger, contract.RESET.name, self.on_reset)
        wall_timer(self, 1.0, self.publish_diagnostics)
        started = time.monotonic()              # before the timer: its calls come at or after the steps' due times
        wall_timer(self, self.session.timer_period, self.on_timer)
        self.session.start(started)
        self.get_logger().info(f'ready: {self.machine.name}, {values.mode}, {len(axes)} axes')

    def check_parameters(self, initial) -> None:
        """What the table cannot say: the initial position against the machine."""
        problems = []
        if len(initial) != len(self.machine.axes) or not all_finite(initial):
            problems.append(f'initial_position needs {len(self.machine.axes)} finite values, got {list(initial)}')
        else:
            outside = [a.name for a, q in zip(self.machine.axes, initial) if not a.in_stroke(q)]
            if outside:
                problems.append(f'initial_position outside the stroke of {", ".join(outside)}')
        if problems:
            self.get_logger().fatal(f'parameters: {"; ".join(problems)}')
            raise SystemExit(2)

    # read by tools and test/test_recorder_graph.py: the recorder gate's holds (none when paced)
    @property
    def recorder_holds(self) -> int:
        return self.session.gate.hold_count

    @property
    def recorder_hold_time(self) -> float:
        """Wall s of the holds ended."""
        return self.session.gate.hold_time

    # -- events: message -> session -------------------------------------------------------
    def on_command(self, msg: JointStateData) -> None:
        self.session.on_command(msg.sec, msg.nanosec, msg.name, msg.effort, time.monotonic())

    def on_progress(self, msg: Time) -> None:
        self.session.on_progress(msg.sec, msg.nanosec, time.monotonic())

    def on_recorder_alive(self, alive: bool) -> None:
        self.session.recorder_alive(alive, time.monotonic())

    def on_timer(self) -> None:
        now = time.monotonic()
        self.session.watch(now)                  # hw_sim's own stall first (README "Faults")
        self.session.on_timer(now)

    def on_reset(self, request, response):
        response.success = True
        response.message = self.session.reset(time.monotonic())
        self.publish_diagnostics()
        return response

    # -- SessionIO: what the session asks of the node ------------------------------------
    def refuse_command(self, reason: str) -> None:
        self.get_logger().warning(f'refused command: {reason}', throttle_duration_sec=1.0)

    def refuse_progress(self, reason: str) -> None:
        self.get_logger().warning(f'refused recorder progress: {reason}', throttle_duration_sec=1.0)

    def log_info(self, text: str) -> None:
        self.get_logger().info(text)

    def report_fault(self, reason: str) -> None:
        self.get_logger().error(f'FAULT, machine stopped: {reason}')
        self.publish_diagnostics()

    def state_subscribers(self) -> int:
        return self.pub_state.get_subscription_count()

    def recorder_connected(self) -> bool:
        return self.sub_progress.get_publisher_count() > 0

    # -- publishing ---------------------------------------------------------------------
    def publish_state(self, step: int) -> None:
        sec, nanosec = self.clock.split(step)
        m = self.sim.measurement
        if self.pub_acceleration is not None and self.pub_acceleration.get_subscription_count():
            stamp = Time(sec=sec, nanosec=nanosec)      # before the state (in one process the state may still come first)
            for i, axis in self.accelerometer_axes:
                self.pub_acceleration.publish(ros_io.accelerometer_message(stamp, axis, m.acceleration[i]))
        if self.pub_tracker is not None and self.pub_tracker.get_subscription_count():
            self.pub_tracker.publish(ros_io.tracker_message(Time(sec=sec, nanosec=nanosec), self.machine.workpiece_frame,
                                                            m.tracker))
        self.pub_state.publish(self.encoder.encode(sec, nanosec, m.position, m.velocity, m.effort))
        if not self.ready_published and self.session.ready:
            self.ready_published = True
            self.pub_ready.publish(Bool(data=True))
            self.get_logger().info(f'graph ready at step {step}')
        if self.session.clock_due(step):
            self.pub_clock.publish(encode_time(sec, nanosec))      # bytes: no rclpy message to build
        if self.session.truth_due(step):
            if self.pub_true.get_subscription_count():
                self.pub_true.publish(self.encoder.encode(sec, nanosec, self.sim.true_position, self.sim.true_velocity))
            if self.pub_pose.get_subscription_count():
                self.pub_pose.publish(ros_io.pose_message(Time(sec=sec, nanosec=nanosec), self.machine.workpiece_frame,
                                                          self.sim.true_tool_pose()))

    def publish_diagnostics(self) -> None:
        now = time.monotonic()
        self.session.watch(now)                  # a stall seen by whichever timer runs first
        status = self.session.status(now)
        if self.sub_recorder_alive is not None:
            status.values['recorder_lost'] = self.session.gate.lost
        level = DiagnosticStatus.ERROR if status.fault else DiagnosticStatus.OK
        self.pub_diag.publish(ros_io.diagnostics(self.clock.stamp(self.session.step), 'hw_sim', level,
                                                 status.message, status.values))


main = main_for(HwSimNode)

if __name__ == '__main__':
    raise SystemExit(main())
