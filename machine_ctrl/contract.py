"""The contract between the nodes, and with anyone outside: every topic and service name,
its standard message type and QoS, the message layout choices, and the step clock.

ROS-free on purpose (README "Architecture"): it sits just above the machine model, so the
cores that meet these names — the recorder and the bag analysis read topics by name, the
simulator's lock-step core counts steps on the clock — need no ROS import, and the nodes
(machine_ctrl/ros) turn :class:`Qos` into rclpy profiles in one place
(:func:`machine_ctrl.ros.messages.qos`; :func:`machine_ctrl.ros.node_common.qos` adds a
liveliness lease). No other module writes a topic or service name, nor
recomputes the control period in nanoseconds; `test/test_architecture.py` checks both.

Units on every topic are SI (m, rad, s, m/s^2; REP 103), except the effort on /joint_states
and /servo_commands, which is in the drive's command units (V, amplifier units); joint names
are the machine's axis names.

Names are relative (README "For ROS users", "Namespaces"): a node in namespace /mill1
publishes `joint_states` as /mill1/joint_states, so several machines share a ROS domain,
each graph under its own namespace. That includes the sim clock: every node of a graph
remaps ROS's absolute /clock to the relative `clock` (:data:`CLOCK_REMAP`), and
/diagnostics, whose readers (the trajectory node learns hw_sim's faults there) must not hear
another machine. ROS's own /rosout and /parameter_events stay global. Bags store the fully
qualified names and their namespace (:func:`absolute`).

Time (design.md "Time"): control step k of a machine with period T happens at sim time
t_k = k*T, carried in stamps as integer nanoseconds; T must be a whole number of
nanoseconds, so step <-> stamp is exact both ways (:class:`StepClock`).
"""
from __future__ import annotations

import re
import signal
from dataclasses import dataclass

from machine_ctrl.model.errors import InvalidMessage

NS_PER_SECOND = 1_000_000_000


# --- QoS, as data -----------------------------------------------------------------------

@dataclass(frozen=True)
class Qos:
    """A QoS profile: keep-last `depth`, reliable or best effort, volatile or transient local
    (late joiners get the last `depth` messages). Deadline and lifespan are the ROS defaults;
    liveliness too unless `liveliness_lease` > 0 (s): automatic liveliness with that lease, so
    a reader that asks for it learns within the lease that the writer's process is gone or
    stopped (README "Faults"). A reader must request a lease at least the writer's: Fast DDS
    reports liveliness changes only to readers with a finite lease."""
    depth: int
    reliable: bool = True
    transient_local: bool = False
    liveliness_lease: float = 0.0


# assumed: 6 s, above the longest stall the transport itself puts on a healthy process. A
# process that publishes into the shared-memory port of a reader that was killed while it
# held that port's lock waits 1 s per send (Fast DDS 2.14: the port mutex is not robust,
# BOOST_INTERPROCESS_TIMEOUT_WHEN_LOCKING_DURATION_MS = 1000, SharedMemGlobal.hpp try_push)
# until the port watchdog (1 s period) drops the port, holding the participant's send lock
# meanwhile, so its liveliness is not asserted either: 1.2-2.4 s measured on loaded runs after
# a recorder's or a `ros2 topic echo`'s SIGKILL (issue [6/8]). With the former 2 s lease
# such a stall read as a lost node. Liveliness is asserted from Fast DDS's own threads (not
# Python), so a busy node is not taken for a lost one. A SIGKILL or SIGSTOP is reported a
# lease after the last assertion the reader got: a data message of the writer, or the
# participant's automatic assertion, sent every 2/3 of the lease (rmw_fastrtps 8.4 qos.cpp
# sets announcement_period = 2/3 lease; Fast DDS 2.14 WLP.cpp asserts at the shortest
# one) — so between a third of the lease and the lease after the stop for a writer that
# sends nothing meanwhile (a latched status); a SIGCONT is reported at once
# (test/test_faults.py checks the behaviour, not the time). hw_sim's command_timeout (5 s)
# is chosen the same way.
LIVELINESS_LEASE = 6.0     # s
# assumed: half the lease, the smallest gap a busy Python process is not expected to show.
# The trajectory node's own stall longer than this aborts its goal (trajectory.session.
# Session.watch): a client following the goal may have been told the node is lost from a
# third of the lease on (above), and once the lease has passed every client's reader has run
# out of it (its report may come a little later: 1.3-1.5 s measured with a 1 s lease, README
# "Faults"), so the node must not go on as if nothing happened. A stall between a third of
# the lease and this limit may have been reported while the goal goes on: accepted, a lower
# limit would take a busy process for a stopped one. Its `stall_limit` parameter (at most the
# lease) sets it.
STALL_LIMIT = LIVELINESS_LEASE / 2     # s
# assumed: 1.5 s, a peer's loss reported by its lease is confirmed when nothing (its 1 Hz
# /diagnostics) is heard from it for this long after the report (machine_ctrl.diagnostics.
# PeerLiveliness: a reader starved by its own node's long callback reports false losses)
LOSS_CONFIRM = 1.5         # s
# assumed: 0.5 s, 10 periods of the watcher's 0.05 s check and half the peers' /diagnostics
# period. A check later than this after the one before means the watching node did not run
# meanwhile (a long callback, a starved or blocked process: in a single-process graph the
# peer stalls with it), so the peer's messages may still be queued or unsent: the
# confirmation starts over (PeerLiveliness; a CI run saw a healthy hw_sim taken for lost)
LOSS_CHECK_GAP = 0.5       # s
# assumed: above the 2.5 s recorder freeze that test_recorder_graph.py must survive holding
# (a freeze longer than this releases hw_sim's hold: the machine goes on, the bag may lose)
RECORDER_LIVELINESS_LEASE = 5.0     # s
# A servo's reference stream that broke while moving (an underrun: the node before it was lost
# or stalled) is held, and taken up again only from a row at rest this close to the position
# held, on every axis (m or rad; machine_ctrl.model.reference.ReferenceBuffer): rows that were
# on their way before the break (queued by a node that continues, re-sent from a writer's
# history to one started again) would move the machine without a goal. assumed: 20 µm / 20
# µrad. The trajectory node takes the stream up again from the very row the servos hold where
# it knows it (trajectory.session.Session.machine_state); from the measured position where it
# does not, which differs by the holding axis's settling and the corrections and offsets added
# once more on the way (up to 10 µm / µrad measured on the micromill's fine stage, issue
# [6/8]): above that, far below a motion's stopping distance, where a stale row at rest stands
REJOIN_TOLERANCE = 20e-6


# A node process prints every thread's Python stack on stderr when it gets this signal
# (faulthandler, from C: also while its main thread is blocked in a call, when no Python
# handler can run); a supervisor sends it before SIGKILL (machine_ctrl.app.processes), so a
# process that did not stop leaves where it hung in its log.
STACKS_SIGNAL = signal.SIGUSR1

# Per-step traffic must never be dropped silently: reliable, and deep enough for bursts.
STEP_QOS = Qos(depth=200)
# A viewer of the per-step streams (machine_ctrl/ros/view_node.py): best effort, so that a
# slow viewer never holds up a writer. assumed: keep last 2, the view's take per sample:
# usually the newest message of each servo on /servo_commands, which publish one step back
# to back (a keyless topic's history does not guarantee it; a plot then misses a sample).
VIEW_STEP_QOS = Qos(depth=2, reliable=False)
# References are streamed ahead in chunks; a node that joins late still gets the last
# chunks (transient local), so no step's reference depends on discovery timing.
REFERENCE_QOS = Qos(depth=50, transient_local=True)
# Goals, overrides and the like from other programs.
COMMAND_QOS = Qos(depth=10)
# A status whose last value a late joiner must see (the trajectory status).
LATCHED_QOS = Qos(depth=1, transient_local=True)
# The goal status list: latched, and deep on the writer's side too. With depth 1 a reliable
# writer overwrites a state its readers have not acknowledged yet, so a client under load
# saw accepted then succeeded, never executing; 100 lists outlast any such lag (each list is
# complete, so a late joiner's newest one is the truth and older ones only history).
# With a liveliness lease: a client following its goal learns that the trajectory node is
# gone (or stopped) within it.
GOAL_STATUS_QOS = Qos(depth=100, transient_local=True, liveliness_lease=LIVELINESS_LEASE)
# What a client keeps of a latched status stream while it follows a motion.
LATCHED_READER_QOS = Qos(depth=1000, transient_local=True)
# The same for the goal status, asking for the writer's liveliness (contract.GOAL_STATUS_QOS).
GOAL_STATUS_READER_QOS = Qos(depth=1000, transient_local=True, liveliness_lease=LIVELINESS_LEASE)
# hw_sim's `ready`: latched, with a liveliness lease, so that the trajectory node learns within
# the lease that hw_sim (the machine) is gone or stopped.
READY_QOS = Qos(depth=1, transient_local=True, liveliness_lease=LIVELINESS_LEASE)
# The recorder's progress: one value, latched, so hw_sim learns at once that a recorder is
# there and how far it is.
# With a liveliness lease, so that hw_sim stops holding for a killed or stopped recorder
# within it (instead of DDS's participant lease, ~20 s).
PROGRESS_QOS = Qos(depth=1, transient_local=True, liveliness_lease=RECORDER_LIVELINESS_LEASE)
# /clock for timers and tools (the per-step nodes take time from the stamps they answer).
CLOCK_READER_QOS = Qos(depth=10)
# /diagnostics: every node, 1 Hz and at once on a fault; the trajectory node also on each
# status change and each goal's change (its reason). assumed: the writer keeps 100 so that such a
# burst does not overwrite a goal's entry before a reader under load has it (a reliable
# keep-last writer drops what it overwrites).
DIAGNOSTICS_QOS = Qos(depth=100)
DIAGNOSTICS_READER_QOS = Qos(depth=50)


# --- Topics and services ----------------------------------------------------------------

_TOKEN = re.compile(r'^[A-Za-z_][A-Za-z0-9_]*$')


def namespace_problem(namespace: str) -> str | None:
    """Why `namespace` is not a ROS namespace ('' and '/' are the root; 'mill1', '/mill1',
    '/plant/mill1' are fine), or None."""
    inner = namespace.strip('/')
    if any(not _TOKEN.match(token) for token in (inner.split('/') if inner else [])):
        return (f'{namespace!r} is not a ROS namespace (names of letters, digits and _, not starting with a '
                'digit, joined by /)')
    return None


def normal_namespace(namespace: str) -> str:
    """'/mill1' for 'mill1', '/mill1' or '/mill1/' ('' for the root); ValueError if invalid."""
    if (problem := namespace_problem(namespace)) is not None:
        raise ValueError(problem)
    inner = namespace.strip('/')
    return f'/{inner}' if inner else ''


def absolute(name: str, namespace: str = '') -> str:
    """The fully qualified name of a relative contract name under `namespace`, as rcl
    resolves it ('joint_states' in '/mill1' -> '/mill1/joint_states'); an absolute name is
    returned as it is."""
    return name if name.startswith('/') else f'{normal_namespace(namespace)}/{name}'


@dataclass(frozen=True)
class Topic:
    name: str                  # relative: resolved in the node's namespace
    type: str                  # 'pkg/msg/Type'
    qos: Qos
    description: str = ''

    def full(self, namespace: str = '') -> str:
        return absolute(self.name, namespace)


@dataclass(frozen=True)
class Service:
    name: str                  # relative
    type: str                  # 'pkg/srv/Type'
    description: str = ''

    def full(self, namespace: str = '') -> str:
        return absolute(self.name, namespace)


CLOCK = Topic('clock', 'rosgraph_msgs/msg/Clock', STEP_QOS, "hw_sim's simulated time")
JOINT_STATES = Topic('joint_states', 'sensor_msgs/msg/JointState', STEP_QOS,
                     'measured position and velocity of every axis, and the effort applied, one per control step')
SERVO_COMMANDS = Topic('servo_commands', 'sensor_msgs/msg/JointState', STEP_QOS,
                       'actuator commands (effort), stamped with the state they answer')
REFERENCE = Topic('reference', 'trajectory_msgs/msg/JointTrajectory', REFERENCE_QOS,
                  'reference chunks the servos follow (one point per step)')
TRAJECTORY_REFERENCE = Topic('trajectory/reference', 'trajectory_msgs/msg/JointTrajectory', REFERENCE_QOS,
                             'uncompensated reference chunks (when compensation runs)')
DUAL_STAGE_OFFSETS = Topic('dual_stage/offsets', 'sensor_msgs/msg/JointState', STEP_QOS,
                           'reference offsets (position) of the fine axes, with mid-ranging the coarse axes too, '
                           'one per step')
ACCELEROMETERS = Topic('accelerometers', 'sensor_msgs/msg/Imu', STEP_QOS,
                       'one per step and accelerometer (published while subscribed): frame_id = the URDF link '
                       'of its axis, linear_acceleration = the reading along the joint axis, m/s^2')
TRACKER = Topic('hw_sim/tracker', 'geometry_msgs/msg/PointStamped', STEP_QOS,
                'the tracking system of a Cartesian coupling (machine config cartesian_dual_stage.tracker): the '
                'coarse stage\'s tool tip (fine axes at home, deflection included), m, frame workpiece; one per step, '
                'before the state (published while subscribed)')
TRUE_JOINT_STATES = Topic('hw_sim/ground_truth/joint_states', 'sensor_msgs/msg/JointState', STEP_QOS,
                          'true axis positions and velocities (published only while subscribed)')
TRUE_TOOL_POSE = Topic('hw_sim/ground_truth/tool_pose', 'geometry_msgs/msg/PoseStamped', STEP_QOS,
                       'true tool pose in the workpiece frame (published only while subscribed)')
DIAGNOSTICS = Topic('diagnostics', 'diagnostic_msgs/msg/DiagnosticArray', DIAGNOSTICS_QOS,
                    'every node: faults, refusals, counters')
PATH = Topic('trajectory/path', 'nav_msgs/msg/Path', COMMAND_QOS,
             'tool path, frame workpiece, m; pose z-axis = tool axis')
JOINT_GOAL = Topic('trajectory/joint_goal', 'trajectory_msgs/msg/JointTrajectory', COMMAND_QOS,
                   'axis goals, m / rad, times s')
PROGRAM = Topic('trajectory/program', 'std_msgs/msg/String', COMMAND_QOS,
                'G-code part program text (trajectory/gcode.py); units from G20/G21')
FEED_OVERRIDE = Topic('trajectory/feed_override', 'std_msgs/msg/Float64', COMMAND_QOS,
                      'feed fraction 0..1, ramped')
TRAJECTORY_STATUS = Topic('trajectory/status', 'diagnostic_msgs/msg/DiagnosticStatus', LATCHED_QOS,
                          'latched: state, progress, refusals')
CONTOUR_TOOL_TIP = Topic('contour_error/tool_tip', 'geometry_msgs/msg/Vector3Stamped', STEP_QOS,
                         'tool-tip contour error vector, m, workpiece frame')
CONTOUR_TOOL_TIP_MAGNITUDE = Topic('contour_error/tool_tip_magnitude', 'std_msgs/msg/Float64', STEP_QOS,
                                   'tool-tip contour error magnitude, m')
CONTOUR_ORIENTATION = Topic('contour_error/orientation', 'geometry_msgs/msg/Vector3Stamped', STEP_QOS,
                            'tool-orientation contour error vector, rad')
CONTOUR_ORIENTATION_MAGNITUDE = Topic('contour_error/orientation_magnitude', 'std_msgs/msg/Float64', STEP_QOS,
                                      'tool-orientation contour error magnitude, rad')
# assumed: the goals each goal status array lists (the active one always): the recent ones a
# client may still follow, a few kB of message
GOAL_STATUS_KEEP = 100
GOAL_STATUS = Topic('trajectory/goal_status', 'action_msgs/msg/GoalStatusArray', GOAL_STATUS_QOS,
                    f'latched: the last {GOAL_STATUS_KEEP} goals (the active one always) with id (UUID) and '
                    'state: accepted, executing, canceling, succeeded, canceled, aborted (the reason on '
                    '/diagnostics)')
COMPENSATION_READY = Topic('compensation/ready', 'std_msgs/msg/Bool', READY_QOS,
                           'latched: true while the compensation node runs; with a liveliness lease, so the '
                           'trajectory node learns that its reference no longer reaches the servos (README "Faults")')
READY = Topic('ready', 'std_msgs/msg/Bool', READY_QOS,
              'latched: true once every node of the graph has its first state (the graph steps)')
ROBOT_DESCRIPTION = Topic('robot_description', 'std_msgs/msg/String', LATCHED_QOS,
                          "latched: the machine's URDF, joint names as on /joint_states")
RECORDER_PROGRESS = Topic('recorder/progress', 'builtin_interfaces/msg/Time', PROGRESS_QOS,
                          "the newest step every per-step publisher's stream has reached in the bag")

HOLD = Service('trajectory/hold', 'std_srvs/srv/Trigger', 'feed hold along the path (program kept)')
RESUME = Service('trajectory/resume', 'std_srvs/srv/Trigger', 'resume after a hold')
STOP = Service('trajectory/stop', 'std_srvs/srv/Trigger', 'stop smoothly and drop the program')
HOME = Service('trajectory/home', 'std_srvs/srv/Trigger', 'move to home (when idle)')
FREEFORM = Service('trajectory/freeform', 'std_srvs/srv/Trigger',
                   'start the spindle-slaved freeform cut of the freeform.* parameters (when idle)')
CANCEL = Service('trajectory/cancel', 'action_msgs/srv/CancelGoal',
                'cancel the active goal by id (zero id: any): stopped as by stop, then canceled')
RESET = Service('hw_sim/reset', 'std_srvs/srv/Trigger', 'clear a fault')
DUAL_STAGE_ENABLE = Service('dual_stage/enable', 'std_srvs/srv/SetBool', 'dual-stage coupling on/off')
COMPENSATION_ENABLE = Service('compensation/enable', 'std_srvs/srv/SetBool',
                              'geometric compensation on/off (with a model)')

# rclpy's sim-time subscription is to the absolute /clock: each node of a graph remaps it to
# its own namespace's clock (a no-op in the root namespace), as (from, to).
CLOCK_REMAP = ('/clock', CLOCK.name)

# The live view's own Foxglove channels (machine_ctrl/view; not ROS topics): the 3D scene
# (foxglove.SceneUpdate) and the tracking errors (JSON).
VIEW_SCENE = '/view/scene'
VIEW_TRACKING_ERROR = '/view/tracking_error'

# ROS's own topics, which a recording leaves out by default.
ROSOUT = '/rosout'
PARAMETER_EVENTS = '/parameter_events'

# The command API a user of the running graph sees (machine-ctrl bringup prints it).
COMMAND_API = (PATH, JOINT_GOAL, PROGRAM, FEED_OVERRIDE, HOLD, RESUME, STOP, CANCEL, HOME, FREEFORM, RESET,
               DUAL_STAGE_ENABLE, COMPENSATION_ENABLE, TRAJECTORY_STATUS, GOAL_STATUS, READY, ROBOT_DESCRIPTION,
               DIAGNOSTICS)
# The per-step streams of the lock-step graph: each publisher publishes on the step grid
# (every step, or every N-th: /clock and the ground truth are decimated), so the recorder's
# progress is the minimum over them.
PER_STEP_TOPICS = (JOINT_STATES, SERVO_COMMANDS, DUAL_STAGE_OFFSETS, CLOCK, ACCELEROMETERS, TRACKER, TRUE_JOINT_STATES,
                   TRUE_TOOL_POSE)
# Of those, the answers of the step nodes to each state (one stream per publisher; the rest
# are hw_sim's own).
STEP_ANSWERS = (SERVO_COMMANDS, DUAL_STAGE_OFFSETS)
TOPICS = (CLOCK, JOINT_STATES, SERVO_COMMANDS, REFERENCE, TRAJECTORY_REFERENCE, DUAL_STAGE_OFFSETS, ACCELEROMETERS,
          TRACKER, TRUE_JOINT_STATES, TRUE_TOOL_POSE, DIAGNOSTICS, PATH, JOINT_GOAL, PROGRAM, FEED_OVERRIDE, TRAJECTORY_STATUS,
          CONTOUR_TOOL_TIP, CONTOUR_TOOL_TIP_MAGNITUDE, CONTOUR_ORIENTATION, CONTOUR_ORIENTATION_MAGNITUDE,
          RECORDER_PROGRESS, GOAL_STATUS, READY, ROBOT_DESCRIPTION, COMPENSATION_READY)
SERVICES = (HOLD, RESUME, STOP, CANCEL, HOME, FREEFORM, RESET, DUAL_STAGE_ENABLE, COMPENSATION_ENABLE)


def trajectory_output(compensated: bool) -> Topic:
    """Where the trajectory node publishes its reference chunks: /reference, which the
    servos read, or with geometric compensation /trajectory/reference, as the compensation
    node sits between."""
    return TRAJECTORY_REFERENCE if compensated else REFERENCE


# --- Message layout choices ---------------------------------------------------------------
# States and commands are sensor_msgs/JointState with the axis names of the machine config
# as joint names: position/velocity for states, effort for servo commands, position for the
# dual-stage offsets. A reference chunk is a trajectory_msgs/JointTrajectory whose header
# stamp is the sim time of its first step and whose point i is step first+i
# (time_from_start = i*T), with positions, velocities and accelerations of every named axis.
# Poses are in the machine's workpiece frame; the tool axis is the pose's z-axis.


# --- The step clock -----------------------------------------------------------------------

def split_ns(ns: int) -> tuple[int, int]:
    """(sec, nanosec) of a time in integer nanoseconds."""
    return divmod(ns, NS_PER_SECOND)


def join_ns(sec: int, nanosec: int) -> int:
    """Integer nanoseconds of (sec, nanosec); InvalidMessage if nanosec is not in [0, 1e9)."""
    if not 0 <= nanosec < NS_PER_SECOND:
        raise InvalidMessage(f'stamp nanosec {nanosec} is not in [0, 1e9)')
    return sec * NS_PER_SECOND + nanosec


_SESSION_FACT = re.compile(r'([A-Za-z][A-Za-z0-9_]*)=(.*)', re.DOTALL)


def session_fact(text: str) -> tuple[str, str]:
    """A fact about a recorded graph (the recorder's `session` parameter), KEY=VALUE with a
    KEY of a letter, then letters, digits and _: (KEY, VALUE); ValueError naming it else."""
    match = _SESSION_FACT.fullmatch(text)
    if match is None:
        raise ValueError(f'{text!r} is not KEY=VALUE (KEY: a letter, then letters, digits, _)')
    return match.group(1), match.group(2)


def seconds_to_ns(seconds: float) -> int:
    return int(round(seconds * NS_PER_SECOND))


def ns_to_seconds(ns: int) -> float:
    return ns / NS_PER_SECOND


def seconds(sec: int, nanosec: int) -> float:
    """A (sec, nanosec) time or duration in seconds (float)."""
    return sec + 1e-9 * nanosec


class StepClock:
    """Control step <-> sim time of a machine (its control period), exact in integer ns."""

    def __init__(self, period: float):
        self.period = period
        self.period_ns = seconds_to_ns(period)
        if self.period_ns <= 0 or abs(self.period_ns - period * NS_PER_SECOND) > 1e-6:
            raise ValueError(f'control period {period!r} s is not a whole number of nanoseconds')

    @classmethod
    def of(cls, machine) -> StepClock:
        """The clock of a machine config (anything with `control_period`)."""
        return cls(machine.control_period)

    def ns(self, step: int) -> int:
        return step * self.period_ns

    def split(self, step: int) -> tuple[int, int]:
        """(sec, nanosec) of step k."""
        return split_ns(step * self.period_ns)

    def step_at(self, sec: int, nanosec: int) -> int:
        """The step of the stamp (sec, nanosec); InvalidMessage if it is off the grid."""
        return self.step_of_ns(join_ns(sec, nanosec))

    def step_of_ns(self, ns: int) -> int:
        step, rest = divmod(ns, self.period_ns)
        if rest:
            raise InvalidMessage(f'stamp {ns} ns is not on the {self.period_ns} ns control grid')
        return step

    def steps(self, seconds: float) -> int:
        """The whole number of steps nearest to a duration in seconds."""
        return int(round(seconds / self.period))
