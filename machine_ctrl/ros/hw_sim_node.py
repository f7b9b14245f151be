"""hw_sim_node: the simulated machine on the ROS graph (design.md "The node graph", "Time").

Publishes /clock (every `clock_decimation` steps), /joint_states (measured positions,
differentiated velocities, efforts = commands applied over the previous period; stamp =
sim time of the step), ground truth every `ground_truth_decimation` steps (default 10:
1 kHz on the micromill) on /hw_sim/ground_truth/joint_states and
/hw_sim/ground_truth/tool_pose (true tool tip in the workpiece frame; no controller
subscribes to them; each is computed and published only while it has a subscriber, as the
true tool pose through the error map costs ~0.15 ms) and /diagnostics (1 Hz wall, and at
once on a fault). Per-step states go out and commands come in as CDR bytes
(machine_ctrl.recording.cdr; standard sensor_msgs/JointState on the wire). Subscribes
/servo_commands (sensor_msgs/JointState: name = axes, effort = commands, stamp = the stamp
of the state answered). Service /hw_sim/reset (std_srvs/Trigger) clears a fault.

Modes (parameter `mode`):
* lockstep (default): step k -> k+1 once every axis has its step-k command. While waiting,
  the current state is re-sent every `republish_period` s (wall) so nodes that joined late
  still answer; nodes answer a repeated stamp with the command they already computed.
  `min_subscribers` > 0 holds the machine at step 0 until that many /joint_states
  subscribers are matched (a recorder that must see every step). `recorder_window` W > 0
  (steps) is flow control for a recorder: once a recorder reports progress on
  /recorder/progress (builtin_interfaces/Time: stamp of the newest state it has written),
  hw_sim does not advance from step k while k minus that step exceeds W, so the recorder's
  backlog stays bounded and nothing is dropped; a recorder that leaves the graph releases
  the hold. Holding delays a run, it never changes it.
* paced: steps on the wall clock at `real_time_factor`, applying the latest command of
  each axis (zero-order hold) and counting missed deadlines (axes without a command for
  the step being taken) — the contract a driver for real hardware implements.

Faults (machine stopped: drives off, axes held; the node keeps running and reporting): a
non-finite command, a stroke violation, a command missing for `command_timeout` s (wall,
lock-step, from step 1 on: at step 0 hw_sim waits for the graph to come up; never while
every command is in hand and hw_sim holds for the recorder). Malformed commands (unknown or
duplicate axes, length mismatch, off-grid or future stamps) and progress reports (off-grid,
not a published step) are refused with the reason on /diagnostics and change nothing.
"""
from __future__ import annotations

import math
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from hw_sim.lockstep import LockStep, RecorderGate
from hw_sim.simulator import MachineSimulator, true_geometry
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.recording.cdr import JointStateData, JointStateEncoder
from machine_ctrl.model.errors import ConfigError
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.ros.node_common import declare, machine_parameter, main_for, subscribe_joint_states, wall_timer
from machine_ctrl.recording.recorder import PROGRESS_TOPIC
from machine_ctrl.ros.recorder_node import PROGRESS_QOS


class HwSimNode(Node):
    def __init__(self, name: str = 'hw_sim', **kwargs):
        super().__init__(name, **kwargs)
        self.machine = machine_parameter(self)
        axes = self.machine.axis_names
        self.mode = declare(self, 'mode', 'lockstep', 'lockstep | paced')
        if self.mode not in ('lockstep', 'paced'):
            self.get_logger().fatal(f"parameter mode: must be lockstep or paced, got {self.mode!r}")
            raise SystemExit(2)
        self.real_time_factor = declare(self, 'real_time_factor', 0.1, 'paced mode: sim time / wall time (<= 1)')
        self.command_timeout = declare(self, 'command_timeout', 2.0, 's (wall) a lock-step command may be late')
        self.clock_decimation = max(1, declare(self, 'clock_decimation', 10, 'publish /clock every N steps'))
        self.republish_period = declare(self, 'republish_period', 0.2, 's (wall) between re-sends while waiting')
        initial = declare(self, 'initial_position', [float(v) for v in self.machine.home],
                          'axis positions at start, axis order (m, rad)')
        self.min_subscribers = declare(self, 'min_subscribers', 0,
                                       'hold at step 0 until /joint_states has this many subscribers')
        self.truth_decimation = declare(self, 'ground_truth_decimation', 10,
                                        'publish ground truth every N steps (0: never)')
        self.gate = RecorderGate(declare(self, 'recorder_window', 0,
                                         'lock-step: steps hw_sim may run ahead of a recorder (0: off)'))

        self.check_parameters(initial)
        self.clock = ros_io.StepClock(self.machine.control_period)
        self.sim = MachineSimulator(self.machine, initial_position=initial)
        self.lockstep = LockStep(axes)
        self.encoder = JointStateEncoder(axes)
        try:
            self.true_tool_pose = true_geometry(self.machine, Kinematics.from_config(self.machine))
        except ConfigError as exc:
            self.get_logger().fatal(str(exc))
            raise SystemExit(2) from None
        self.missed_deadlines = 0
        self._latest = {}                        # paced mode: last command per axis
        self._start_announced = False
        self._state_sent_at = self._step_started_at = time.monotonic()
        self._hold_started = None                # wall time hw_sim began holding for the recorder
        self.recorder_holds, self.recorder_hold_time = 0, 0.0

        # per-step traffic when clock_decimation is 1; deep like the states, so a recorder
        # that hw_sim lets fall recorder_window steps behind loses no /clock either
        self.pub_clock = self.create_publisher(Clock, '/clock', ros_io.STEP_QOS)
        self.pub_state = self.create_publisher(JointState, ros_io.TOPIC_JOINT_STATES, ros_io.STEP_QOS)
        self.pub_true = self.create_publisher(JointState, ros_io.TOPIC_TRUE_JOINT_STATES, ros_io.STEP_QOS)
        self.pub_pose = self.create_publisher(PoseStamped, ros_io.TOPIC_TRUE_TOOL_POSE, ros_io.STEP_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, ros_io.TOPIC_DIAGNOSTICS, 10)
        subscribe_joint_states(self, ros_io.TOPIC_COMMANDS, self.on_command, self.refuse)
        self.sub_progress = (self.create_subscription(Time, PROGRESS_TOPIC, self.on_progress, PROGRESS_QOS)
                             if self.gate.window > 0 else None)
        self.create_service(Trigger, '/hw_sim/reset', self.on_reset)
        wall_timer(self, 1.0, self.publish_diagnostics)
        if self.mode == 'lockstep':
            wall_timer(self, min(self.republish_period, self.command_timeout / 4), self.on_watchdog)
        else:
            wall_timer(self, self.machine.control_period / self.real_time_factor, self.on_paced_tick)
        self.publish_state()
        self.get_logger().info(f'ready: {self.machine.name}, {self.mode}, {len(axes)} axes')

    def check_parameters(self, initial) -> None:
        problems = []
        if not 0.0 < self.real_time_factor <= 1.0:
            problems.append(f'real_time_factor must be in (0, 1], got {self.real_time_factor}')
        if self.command_timeout <= 0.0 or self.republish_period <= 0.0:
            problems.append('command_timeout and republish_period must be > 0')
        if self.gate.window < 0 or (self.gate.window > 0 and self.mode != 'lockstep'):
            problems.append(f'recorder_window must be >= 0 and needs mode lockstep, got {self.gate.window}')
        if len(initial) != len(self.machine.axes) or not ros_io.all_finite(initial):
            problems.append(f'initial_position needs {len(self.machine.axes)} finite values, got {list(initial)}')
        else:
            outside = [a.name for a, q in zip(self.machine.axes, initial) if not a.in_stroke(q)]
            if outside:
                problems.append(f'initial_position outside the stroke of {", ".join(outside)}')
        if problems:
            self.get_logger().fatal(f'parameters: {"; ".join(problems)}')
            raise SystemExit(2)

    # -- stepping ----------------------------------------------------------------------
    def on_command(self, msg: JointStateData) -> None:
        try:
            step = self.clock.step_at(msg.sec, msg.nanosec)
        except ros_io.InvalidMessage as exc:
            self.refuse(str(exc))
            return
        values = msg.effort
        if len(values) == len(msg.name) and not ros_io.all_finite(values):
            bad = [n for n, v in zip(msg.name, values) if not math.isfinite(v)]
            self.fault(f'non-finite command for {", ".join(bad)}')
            return
        if self.mode == 'paced':
            if step == self.lockstep.step and len(values) == len(msg.name):
                self._latest.update((n, v) for n, v in zip(msg.name, values) if n in self.lockstep.axis_names)
            return
        reason = self.lockstep.offer(step, msg.name, values)
        if reason is not None:
            self.refuse(reason)
            return
        self.advance_if_ready()

    def advance_if_ready(self) -> None:
        if not (self.lockstep.complete() and self.sim.fault is None):
            return
        if self.lockstep.step == 0 and not self._start_announced:
            if self.pub_state.get_subscription_count() < self.min_subscribers:
                return                       # hold at step 0 until e.g. a recorder is matched
            self._start_announced = True
            self.publish_state(resend=True)  # step 0 again, now that every subscriber is there
        if self.holding_for_recorder():
            return
        self.advance(self.lockstep.take())

    def holding_for_recorder(self) -> bool:
        """Whether the recorder is more than recorder_window steps behind (and still there);
        keeps the hold count and time."""
        holds = self.gate.holds(self.lockstep.step)
        if not holds and self._hold_started is None:
            return False                         # the usual case, every step
        if holds and self.sub_progress.get_publisher_count() == 0:
            self.get_logger().info('recorder left the graph: no longer holding for it')
            self.gate.recorded = None
            holds = False
        now = time.monotonic()
        if holds and self._hold_started is None:
            self._hold_started = now
            self.recorder_holds += 1
        elif not holds and self._hold_started is not None:
            self.recorder_hold_time += now - self._hold_started
            self._hold_started = None
        return holds

    def on_progress(self, msg: Time) -> None:
        try:
            step = self.clock.step_at(msg.sec, msg.nanosec)
            if not 0 <= step <= self.lockstep.step:
                raise ValueError(f'progress for step {step}, but the published steps are 0..{self.lockstep.step}')
        except ValueError as exc:
            self.gate.refuse(str(exc))
            self.get_logger().warning(f'refused recorder progress: {exc}', throttle_duration_sec=1.0)
            return
        if self.gate.recorded is None:
            self.get_logger().info(f'recorder reports progress: holding at most {self.gate.window} steps ahead')
        self.gate.recorded = step
        self.advance_if_ready()

    def advance(self, commands) -> None:
        was_ok = self.sim.fault is None
        self.sim.step(commands)
        if was_ok and self.sim.fault is not None:
            self.report_fault()
        self.publish_state()

    def on_watchdog(self) -> None:
        now = time.monotonic()
        if (self.sim.fault is None and self.lockstep.step > 0 and not self.lockstep.complete()
                and now - self._step_started_at > self.command_timeout):
            self.fault(f'missing command for {" ".join(self.lockstep.missing)} '
                       f'(no answer to step {self.lockstep.step} within {self.command_timeout:g} s)')
        elif now - self._state_sent_at > self.republish_period:
            self.publish_state(resend=True)      # late joiners; idempotent for the nodes
        self.advance_if_ready()                  # e.g. a recorder matched meanwhile

    def on_paced_tick(self) -> None:
        axes = self.lockstep.axis_names
        missed = [a for a in axes if a not in self._latest]
        self.missed_deadlines += len(missed)
        held = dict(zip(axes, self.sim.applied))
        commands = [self._latest.get(a, held[a]) for a in axes]
        self._latest.clear()
        self.lockstep.restart(self.lockstep.step + 1)
        self.advance(commands)

    # -- faults and reset ------------------------------------------------------------------
    def refuse(self, reason: str) -> None:
        self.get_logger().warning(f'refused command: {reason}', throttle_duration_sec=1.0)

    def fault(self, reason: str) -> None:
        if self.sim.fault is None:
            self.sim.stop(reason)
            self.report_fault()
            self.publish_state()

    def report_fault(self) -> None:
        self.get_logger().error(f'FAULT, machine stopped: {self.sim.fault}')
        self.publish_diagnostics()

    def on_reset(self, request, response):
        held = self.sim.true_position
        clipped = [min(max(q, a.stroke[0]), a.stroke[1]) if a.stroke else q
                   for q, a in zip(held, self.machine.axes)]
        previous = self.sim.fault
        self.sim.reset(initial_position=clipped)
        self.lockstep.restart(self.lockstep.step)
        response.success = True
        response.message = f'reset at step {self.lockstep.step}' + (f' (cleared: {previous})' if previous else '')
        self.publish_state()
        self.publish_diagnostics()
        return response

    # -- publishing ---------------------------------------------------------------------
    def publish_state(self, resend: bool = False) -> None:
        step = self.lockstep.step
        sec, nanosec = divmod(step * self.clock.period_ns, 1_000_000_000)
        m = self.sim.measurement
        self.pub_state.publish(self.encoder.encode(sec, nanosec, m.position, m.velocity, m.effort))
        if step % self.clock_decimation == 0:
            self.pub_clock.publish(Clock(clock=Time(sec=sec, nanosec=nanosec)))
        if self.truth_decimation > 0 and step % self.truth_decimation == 0:
            if self.pub_true.get_subscription_count():
                self.pub_true.publish(self.encoder.encode(sec, nanosec, self.sim.true_position, self.sim.true_velocity))
            if self.pub_pose.get_subscription_count():
                self.pub_pose.publish(ros_io.pose_message(Time(sec=sec, nanosec=nanosec), self.machine.workpiece_frame,
                                                          self.true_tool_pose(self.sim.true_position)))
        self._state_sent_at = time.monotonic()
        if not resend:
            self._step_started_at = self._state_sent_at

    def publish_diagnostics(self) -> None:
        fault = self.sim.fault
        level = DiagnosticStatus.ERROR if fault else DiagnosticStatus.OK
        stats = self.lockstep.stats
        values = {'step': self.lockstep.step, 'mode': self.mode, 'fault': fault or '',
                  'waiting_for': ' '.join(self.lockstep.missing) if self.mode == 'lockstep' else '',
                  'stale_commands': stats.stale, 'refused_commands': stats.refused,
                  'last_refusal': stats.last_refusal, 'missed_deadlines': self.missed_deadlines}
        if self.gate.window > 0:
            held = self.recorder_hold_time + (time.monotonic() - self._hold_started if self._hold_started else 0.0)
            values.update({'recorder_window': self.gate.window,
                           'recorder_step': '' if self.gate.recorded is None else self.gate.recorded,
                           'holding_for_recorder': self._hold_started is not None,
                           'recorder_holds': self.recorder_holds, 'recorder_hold_time': f'{held:.3f}',
                           'refused_progress': self.gate.refused, 'last_progress_refusal': self.gate.last_refusal})
        message = f'FAULT: {fault}' if fault else f'running, step {self.lockstep.step}'
        self.pub_diag.publish(ros_io.diagnostics(self.clock.stamp(self.lockstep.step), 'hw_sim', level,
                                                 message, values))


main = main_for(HwSimNode)

if __name__ == '__main__':
    raise SystemExit(main())
