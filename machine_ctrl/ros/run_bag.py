"""An offline run (:mod:`hw_sim.offline`) written as the bag the lock-step graph would
record: same topics, types, stamps and contents per step k (stamp t_k = k T):

* /joint_states: measured position, velocity and the efforts applied over the period before;
* /servo_commands: one message per servo node of the default graph (coarse, fine), effort =
  the commands computed at k;
* /dual_stage/offsets: the coupling's offsets (of MachineConfig.offset_axes; zero with the
  coupling off), if the machine has a dual-stage coupling;
* /hw_sim/tracker: the tracker's reading of each step, if the machine has a tracker;
* /reference: chunks of ``CHUNK_STEPS`` rows as reference_node sends them;
* /clock every ``CLOCK_DECIMATION`` steps and the ground truth
  (/hw_sim/ground_truth/joint_states: true positions — the offline record keeps no true
  velocities, so that field is empty — and the true tool pose) every
  ``TRUTH_DECIMATION`` steps (the nodes' defaults).

There is no wall clock offline: log and publish times are the sim time of the message.

:func:`write_goal_bag` does the same for a tool-path goal run offline (hw_sim.offline_goal:
the trajectory node's session streams the reference, from hw_sim's initial position): the
bag `machine-ctrl bringup --record` + `machine-ctrl send` record, for these topics.
"""
from __future__ import annotations

from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock

from hw_sim.offline_goal import GoalRun, run_goal
from hw_sim.simulator import true_geometry
from hw_sim.tool_deflection import deflected, deflections
from machine_ctrl import contract, parameters
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.recording.bag import BagWriter, qos_profile
from machine_ctrl.model.config import MachineConfig
from machine_ctrl.ros.graph import default_graph
from machine_ctrl.recording.recorder import MACHINE_FILE_KEY, MACHINE_KEY

CHUNK_STEPS = parameters.REFERENCE.spec('chunk_steps').default
CLOCK_DECIMATION = parameters.HW_SIM.spec('clock_decimation').default
TRUTH_DECIMATION = parameters.HW_SIM.spec('ground_truth_decimation').default


def _offered(qos: contract.Qos) -> dict:
    """A contract QoS as the bag stores an offered profile."""
    return qos_profile(reliability='reliable' if qos.reliable else 'best_effort',
                       durability='transient_local' if qos.transient_local else 'volatile', depth=qos.depth)


# the topics in the order the bag lists them, with the QoS offered: the contract's, but
# /clock with the depth these bags have always had (contract.CLOCK_READER_QOS; hw_sim
# offers contract.CLOCK.qos)
_TOPICS = [(topic, _offered(topic.qos if topic is not contract.CLOCK else contract.CLOCK_READER_QOS))
           for topic in (contract.JOINT_STATES, contract.SERVO_COMMANDS, contract.DUAL_STAGE_OFFSETS,
                         contract.TRACKER, contract.REFERENCE, contract.CLOCK, contract.TRUE_JOINT_STATES,
                         contract.TRUE_TOOL_POSE)]


def servo_groups(machine: MachineConfig) -> list[list[str]]:
    """The axes of each servo node of the default graph, in start order."""
    return [list(s.parameters['axes']) for s in default_graph(machine, contour=None)
            if s.module == 'machine_ctrl.ros.servo_node']


def write_run_bag(directory, machine: MachineConfig, reference, record, label: str = '') -> dict[str, int]:
    """Write `record` (offline.RunRecord of `reference`) as a bag; returns the counts."""
    writer = BagWriter(directory)
    has_offsets = bool(machine.offset_axes)
    has_tracker = record.tracker is not None
    for topic, qos in _TOPICS:
        if (topic is not contract.DUAL_STAGE_OFFSETS or has_offsets) and (topic is not contract.TRACKER or has_tracker):
            writer.add_topic(topic.full(), topic.type, [qos])
    clock = ros_io.StepClock.of(machine)
    axes = list(machine.axis_names)
    groups = [(g, [axes.index(a) for a in g]) for g in servo_groups(machine)]
    true_tool_pose = true_geometry(machine)     # what hw_sim publishes (its error map included) ...
    deflection = deflections(machine, true_tool_pose, record.true)     # ... and its structure's deflection
    steps = len(record.measured)

    def put(topic, msg, ns):
        writer.write(topic, msg if isinstance(msg, bytes) else serialize_message(msg), ns)

    for k in range(steps):
        stamp = clock.stamp(k)
        ns = clock.ns(k)
        if k % CHUNK_STEPS == 0:
            rows = [reference.row(i) for i in range(k, k + CHUNK_STEPS)]
            put(contract.REFERENCE.full(), ros_io.trajectory_chunk(clock, k, axes, *zip(*rows)), ns)
        if k % CLOCK_DECIMATION == 0:
            put(contract.CLOCK.full(), Clock(clock=stamp), ns)
        if k % TRUTH_DECIMATION == 0:
            put(contract.TRUE_JOINT_STATES.full(), ros_io.joint_state(stamp, axes, record.true[k]), ns)
            put(contract.TRUE_TOOL_POSE.full(), ros_io.pose_message(stamp, machine.workpiece_frame,
                                                                     deflected(true_tool_pose(record.true[k]),
                                                                               deflection[k])), ns)
        if has_tracker:          # hw_sim publishes it before the step's state
            put(contract.TRACKER.full(), ros_io.tracker_message(stamp, machine.workpiece_frame,
                                                                record.tracker[k].tolist()), ns)
        put(contract.JOINT_STATES.full(), ros_io.joint_state(stamp, axes, record.measured[k],
                                                          record.measured_velocity[k], record.effort[k]), ns)
        if has_offsets:
            put(contract.DUAL_STAGE_OFFSETS.full(), ros_io.joint_state(stamp, record.offset_axes, record.offsets[k]), ns)
        for names, index in groups:
            put(contract.SERVO_COMMANDS.full(), ros_io.joint_state(stamp, names, effort=record.commands[k, index]), ns)
    custom = {MACHINE_KEY: machine.name, MACHINE_FILE_KEY: str(machine.yaml_path)}
    if label:
        custom['machine_ctrl.run'] = label
    return writer.close(custom)


def as_received(machine: MachineConfig, cl):
    """CL data as the trajectory node gets them from a client: sent as a nav_msgs/Path
    (tool axis as a quaternion, ros_io.path_message, as MachineClient.send_path does) and
    read back (ros_io.path_to_cl), so the planner sees the same floats."""
    frame = machine.workpiece_frame
    return ros_io.path_to_cl(ros_io.path_message(cl, frame), frame)


def write_goal_bag(directory, machine: MachineConfig, cl, start_step: int | None = None,
                   steps: int | None = None, initial_position=None) -> tuple[GoalRun, dict[str, int]]:
    """Run the tool path `cl` offline as a goal sent to the graph (hw_sim.offline_goal.run_goal:
    the motion from `start_step`, `steps` steps) and write it as a bag; returns the run and
    the counts per topic."""
    run = run_goal(machine, as_received(machine, cl), start_step=start_step, steps=steps,
                   initial_position=initial_position)
    label = f'goal: path of {len(cl)} points, motion from step {run.motion_start} to {run.motion_end}'
    return run, write_run_bag(directory, machine, run.reference, run.record, label)
