"""trajectory_node in the running lock-step graph (hw_sim, servos, dual_stage, trajectory;
all in one process, a process per node for the fault test; real DDS), driven only through
its topics and services (machine_ctrl.app.client): refused goals move nothing, a tool path
runs end to end after an approach from where the machine stands, joint goals, home, feed
hold, fault and reset; the goal status (ids, lifecycle, cancel; a goal sent with the real
`ros2 topic pub`), the graph's readiness and its robot_description."""
import math
import shutil
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
from limit_checks import assert_within_limits

from machine_ctrl import contract
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.app.client import MachineClient
from machine_ctrl.ros.graph import default_graph, single_process_argv
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.app.processes import Supervisor
from ros_fixtures import private_context, wait_until
from trajectory import moves, toolpath

START = [1e-3, -0.5e-3, 0.2e-3, 0, 0, 0, 0, 0, 0]      # hw_sim's initial position, away from home


class Client(MachineClient):
    """The command API plus what the test observes: /reference rows, /diagnostics and the
    true joint positions."""

    def __init__(self, node, machine):
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState
        from trajectory_msgs.msg import JointTrajectory

        self.rows = {}                     # step -> reference position, as the servos hold them
        self.end = 0                       # first step after the newest chunk
        self.diagnostics = {}
        self.truth = None
        self.lock = threading.Lock()
        self.clock = ros_io.StepClock(machine.control_period)
        deep = QoSProfile(depth=100_000, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(JointTrajectory, contract.REFERENCE.name, self.on_reference, deep)
        node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, self.on_diagnostics, 100)
        node.create_subscription(JointState, contract.TRUE_JOINT_STATES.name, self.on_truth, 10)
        super().__init__(node, machine)

    def on_reference(self, msg):
        """As a servo's buffer (machine_ctrl.model.reference.ReferenceBuffer): a chunk replaces
        every row from its first step on. (A re-stream after a stop can end before the stream it
        replaces did: the rows after it are no longer the reference, and a loaded run that kept
        them saw a jump of 326x the velocity limit there.)"""
        first, positions, _, _ = ros_io.parse_chunk(self.clock, msg, self.machine.axis_names)
        with self.lock:
            for step in range(first, self.end):
                self.rows.pop(step, None)
            for i, p in enumerate(positions):
                self.rows[first + i] = p
            self.end = first + len(positions)

    def on_diagnostics(self, msg):
        for status in msg.status:
            self.diagnostics[status.name] = {kv.key: kv.value for kv in status.values}

    def on_truth(self, msg):
        self.truth = np.array(msg.position)

    def wait_goal(self, stamp, states, timeout: float = 120.0, check=None) -> str:
        """Wait until the goal sent with `stamp` has gone through `states` (in order; states
        between may have been missed by the latched status, never the last); its id."""
        def seen() -> bool:
            goal_id = self.goal_of(stamp)
            wanted = list(states)
            for state in self.goal_states.get(goal_id, []) if goal_id else []:
                if wanted and state == wanted[0]:
                    wanted.pop(0)
            return not wanted
        self.wait(seen, f'goal states {list(states)}', timeout, check)
        return self.goal_of(stamp)

    def reference(self):
        """The streamed reference as one array, steps first..last."""
        with self.lock:
            steps = sorted(self.rows)
            assert steps == list(range(steps[0], steps[-1] + 1)), 'the stream has a gap'
            return steps[0], np.array([self.rows[k] for k in steps])

    def send_raw_path(self, positions, quaternions, frame):
        """A path from raw pose arrays (invalid ones too)."""
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.msg import Path
        msg = Path()
        msg.header.frame_id = frame
        for p, q in zip(positions, quaternions):
            pose = PoseStamped()
            pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = map(float, p)
            o = pose.pose.orientation
            o.x, o.y, o.z, o.w = map(float, q)
            msg.poses.append(pose)
        self.pub_path.publish(msg)


def arc(machine, points=24, radius=1e-3):
    """A half circle of tool tips starting at the home tool tip, tool axis +z."""
    tip, _ = Kinematics.from_config(machine).forward(np.zeros(len(machine.axes)))
    th = np.linspace(0.0, math.pi, points)
    p = np.column_stack([tip[0] + radius * (np.cos(th) - 1), tip[1] + radius * np.sin(th), np.full(points, tip[2])])
    return p, np.tile([0.0, 0.0, 1.0], (points, 1))


def graph_specs(micromill):
    return default_graph(micromill, contour=None, hw_sim={'initial_position': START})


@pytest.fixture(scope='module')
def graph(micromill, ros_env, tmp_path_factory):
    """The graph's nodes in one process (`bringup --single-process`): the nodes' behaviour is
    the subject here, and one process steps about 3x as fast as a process per node
    (test_determinism: both step bit for bit alike). The fault test below restarts it as a
    process per node, to stop one servo."""
    logs = tmp_path_factory.mktemp('logs')
    with Supervisor(ros_env, log_dir=logs, stop_timeout=3.0) as supervisor:
        supervisor.start('graph', single_process_argv(graph_specs(micromill), logs))
        yield supervisor


@pytest.fixture(scope='module')
def client(micromill, graph, ros_env):
    import rclpy
    with private_context(ros_env) as context:
        node = rclpy.create_node('trajectory_client', context=context)
        c = Client(node, micromill)
        try:
            c.wait_ready(60, graph.check)                      # hw_sim: the graph has stepped
            # the trajectory node streams from the step it sees; its status may come later than hw_sim's
            # readiness (a race that failed once under load with an immediate assert)
            c.wait(lambda: c.status().get('streamed_to_step', '') not in ('', None),
                   'the trajectory node to stream', 60, graph.check)
            # goal entries go out once per change on the volatile /diagnostics: heard the node
            # there first, so that the first goal's entries are not published before the match
            c.wait(lambda: 'trajectory' in c.diagnostics_heard, "the trajectory node's /diagnostics", 60, graph.check)
            c.wait_listening(60, graph.check, c.command_publishers)   # no command before the match
            yield c
        finally:
            c.close()
            node.destroy_node()


BAD_GOALS = [
    ('path', dict(frame='map'), "frame_id 'map' is not the workpiece frame"),
    ('path', dict(points=5), 'need at least'),
    ('path', dict(nan=True), 'not finite'),
    ('path', dict(zero_axis=True), 'zero length'),
    ('path', dict(repeat=True), 'repeats point'),
    ('path', dict(shift=0.2), 'planning failed: the path starts out of reach inside the strokes: x_c at -0.19'),
    ('goal', (['x_c', 'q_z'], [[1e-3, 0.0]]), 'unknown joints q_z'),
    ('goal', (['x_c', 'x_c'], [[1e-3, 1e-3]]), 'duplicate joint names'),
    ('goal', (['x_c', 'y_c'], [[1e-3]]), '1 positions for 2 joints'),
    ('goal', (['x_c'], [[float('nan')]]), 'NaN or inf'),
    ('goal', (['x_f'], [[0.5e-3]]), 'outside its stroke'),
    ('goal', (['x_c'], [[1e-3], [2e-3]], [0.2, 0.1]), 'strictly increasing'),
    ('goal', (['x_c'], []), 'no points'),
    # the two goals that got no word: a time it cannot meet (x_c starts at 1 mm), a turn count
    # beyond a goal's length
    ('goal_ns', (['x_c'], [[2e-3]], [1000]), 'point 0: 1 mm in 1 µs on x_c needs 1000 m/s (limit 150 mm/s); '
                                             'earliest time_from_start 0.0684 s'),
    ('goal', (['c_f'], [[1e9]]), 'point 0: the joint goal would last at least 1.59155e+08 s up to it'),
]


def send_bad(client, machine, kind, spec):
    if kind == 'goal':
        client.send_goal(*spec)
        return
    if kind == 'goal_ns':           # times in ns as given (send_goal puts them on the control grid)
        from builtin_interfaces.msg import Duration
        from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
        names, points, times = spec
        msg = JointTrajectory(joint_names=names, points=[
            JointTrajectoryPoint(positions=values, time_from_start=Duration(sec=t // 10**9, nanosec=t % 10**9))
            for values, t in zip(points, times)])
        msg.header.stamp = client.stamp_now()
        client.pub_goal.publish(msg)
        return
    p, o = arc(machine, points=spec.get('points', 24))
    if spec.get('nan'):
        p[3, 1] = float('nan')
    if spec.get('zero_axis'):
        o[4] = 0.0
    if spec.get('repeat'):
        p[6] = p[5]
    p[:, 0] += spec.get('shift', 0.0)
    quaternions = [(0.0, 0.0, 0.0, 0.0) if not o_i.any() else ros_io.quaternion_z_to(o_i) for o_i in o]
    client.send_raw_path(p, quaternions, spec.get('frame', 'workpiece'))


def test_invalid_goals_are_refused_with_the_reason_and_nothing_moves(micromill, graph, client):
    client.wait(lambda: client.truth is not None, 'ground truth', check=graph.check)
    before = client.truth.copy()
    for kind, spec, reason in BAD_GOALS:
        count = int(client.status().get('rejected_goals', 0))
        send_bad(client, micromill, kind, spec)
        client.wait(lambda: int(client.status().get('rejected_goals', 0)) == count + 1, f'refusal of {spec}',
                    check=graph.check)
        assert reason in client.status()['last_rejection'], (spec, client.status()['last_rejection'])
        assert client.status()['state'] == 'idle'
    first, reference = client.reference()
    assert (reference == reference[0]).all()                   # the stream only ever held
    np.testing.assert_allclose(reference[0], START, atol=50e-9)  # ... the measured start position
    rotary = np.array([a.unit == 'rad' for a in micromill.axes])
    moved = np.abs(client.truth - before)
    # the table's noise-driven tilt jitter reaches ~20 urad peak to peak (force noise)
    assert moved[~rotary].max() < 1e-6 and moved[rotary].max() < 100e-6
    assert graph.alive() == ['graph']                           # nothing in it died
    assert {spec.name for spec in graph_specs(micromill)} <= set(client.node.get_node_names())


def test_path_runs_end_to_end_after_an_approach_from_where_the_machine_is(micromill, graph, client):
    held_from = client.reference()[1][-1]
    p, o = arc(micromill)
    n = len(client.statuses)
    client.send_path(toolpath.from_arrays(p, o))
    client.wait_states(n, ['running', 'idle'], check=graph.check)
    status = client.status()
    start, end = int(status['motion_start_step']), int(status['motion_end_step'])
    client.wait(lambda: int(client.status()['step']) > end + 100, 'settling', check=graph.check)
    client.wait(lambda: end in client.rows, 'the motion streamed', check=graph.check)   # /reference: its own topic

    first, reference = client.reference()
    motion = reference[start - first:end - first + 1]
    np.testing.assert_array_equal(motion[0], held_from)        # the approach starts where the machine was held
    assert np.abs(motion[0] - START).max() < 50e-9             # = the measured position
    assert_within_limits(micromill, reference)                 # no jump anywhere in the stream
    kin = Kinematics.from_config(micromill)
    tip, axis = kin.forward(motion[-1])
    np.testing.assert_allclose(tip, p[-1], atol=1e-9)
    np.testing.assert_allclose(axis, o[-1], atol=1e-9)
    client.wait(lambda: np.linalg.norm(kin.forward(client.truth)[0] - p[-1]) < 2e-6, 'the machine following',
                check=graph.check)                              # hw_sim's truth: its own topic
    for servo in ('servo_coarse', 'servo_fine'):
        client.wait(lambda: servo in client.diagnostics, f'{servo} diagnostics', check=graph.check)
        assert client.diagnostics[servo]['reference_underruns'] == '0'


def test_joint_goal_home_and_feed_hold(micromill, graph, client):
    n = len(client.statuses)
    client.send_goal(['x_c', 'y_c'], [[3e-3, 1e-3], [4e-3, -1e-3]], [0.0, 0.0])
    client.wait_states(n, ['running', 'idle'], check=graph.check)
    client.wait(lambda: client.truth is not None and abs(client.truth[1] + 1e-3) < 2e-6, 'reaching the goal',
                check=graph.check)
    assert abs(client.truth[0] - 4e-3) < 2e-6

    # a long move (at a quarter of the feed, so that it lasts ~1.3 s of machine time whatever
    # the lag of the node's view of the sim time), held while under way: it stops short of
    # the goal and stays held; the goal is reached after resume
    client.set_feed_override(0.25)
    client.wait(lambda: client.status()['feed_override_setting'] == '0.25', 'setting', check=graph.check)
    n = len(client.statuses)
    client.send_goal(['x_c'], [[-40e-3]])
    client.wait_states(n, ['running'], check=graph.check)
    status = client.status()
    start = int(status['motion_start_step'])
    client.wait(lambda: int(client.status()['step']) > start + 1500, 'motion under way', check=graph.check)
    refused = int(client.status()['rejected_goals'])
    client.send_goal(['y_c'], [[0.0]])                          # one motion at a time
    client.wait(lambda: int(client.status()['rejected_goals']) == refused + 1, 'refusal', check=graph.check)
    assert 'busy (running)' in client.status()['last_rejection']
    success, message = client.call('/trajectory/hold')
    assert success, message
    client.wait(lambda: client.status()['feed_override'] == '0.0000', 'standstill', check=graph.check)
    held_at = int(client.status()['step'])
    client.wait(lambda: int(client.status()['step']) > held_at + 2000, 'time passing', check=graph.check)
    assert client.status()['state'] == 'holding'
    first, reference = client.reference()
    assert_within_limits(micromill, reference)
    still = reference[-1]
    assert -40e-3 + 1e-3 < still[0] < 4e-3 - 1e-3 and (reference[-1000:] == still).all()   # stopped on the way
    n = len(client.statuses)
    assert client.call('/trajectory/resume')[0]
    client.wait_states(n, ['running', 'idle'], check=graph.check)
    first, reference = client.reference()
    assert_within_limits(micromill, reference)
    client.wait(lambda: abs(client.truth[0] + 40e-3) < 2e-6, 'the goal after resume', check=graph.check)

    # feed override: fractions only; at 50 % the next move takes about twice as long
    for bad in (1.5, -0.1, float('nan')):
        refused = int(client.status()['rejected_goals'])
        client.set_feed_override(bad)
        client.wait(lambda: int(client.status()['rejected_goals']) == refused + 1, 'refusal', check=graph.check)
        assert 'not a fraction' in client.status()['last_rejection']
    client.set_feed_override(0.5)
    client.wait(lambda: client.status()['feed_override_setting'] == '0.5', 'setting', check=graph.check)
    n = len(client.statuses)
    client.send_goal(['x_c'], [[-30e-3]])
    client.wait_states(n, ['running', 'idle'], check=graph.check)
    half = client.statuses[-1]
    planned = len(moves.move_to(micromill, [-30e-3] + list(client.reference()[1][-1][1:]),
                                moves.AxisState.at_rest([-40e-3] + list(client.reference()[1][-1][1:]))))
    values = {kv.key: kv.value for kv in half.values}
    took = int(values['motion_end_step']) - int(values['motion_start_step'])
    assert 1.9 * planned < took < 2.1 * planned
    client.set_feed_override(1.0)

    # stop: the motion ends at rest short of its goal, the state is idle (at a quarter of the
    # feed, as the hold above: at full feed the move is over within ~5,400 steps, and a
    # loaded run saw the stop come too late for it and be refused)
    client.set_feed_override(0.25)
    client.wait(lambda: client.status()['feed_override_setting'] == '0.25', 'setting', check=graph.check)
    n = len(client.statuses)
    client.send_goal(['x_c'], [[40e-3]])
    client.wait_states(n, ['running'], check=graph.check)
    start = int(client.status()['motion_start_step'])
    client.wait(lambda: int(client.status()['step']) > start + 1500, 'motion under way', check=graph.check)
    assert client.call('/trajectory/stop')[0]
    client.wait_states(n, ['holding', 'idle'], check=graph.check)
    client.set_feed_override(1.0)
    first, reference = client.reference()
    assert_within_limits(micromill, reference)
    assert -30e-3 < reference[-1][0] < 40e-3 - 1e-3

    assert not client.call('/trajectory/hold')[0]               # nothing to hold now
    n = len(client.statuses)
    assert client.call('/trajectory/home')[0]
    client.wait_states(n, ['running', 'idle'], check=graph.check)
    client.wait(lambda: np.abs(client.truth[:3]).max() < 2e-6, 'home', check=graph.check)


def test_every_goal_has_an_id_and_its_lifecycle_on_the_goal_status(micromill, graph, client):
    n = len(client.statuses)
    stamp = client.send_goal(['y_c'], [[-1e-3]])
    goal_id = client.wait_goal(stamp, ['accepted', 'executing', 'succeeded'], check=graph.check)
    assert client.goal_states[goal_id] == ['accepted', 'executing', 'succeeded']   # each change latched
    client.wait(lambda: client.goal_entries.get(goal_id, {}).get('status') == 'succeeded', 'its diagnostics entry',
                check=graph.check)
    entry = client.goal_entries[goal_id]
    assert entry['label'] == 'joint goal (1 points)' and entry['kind'] == 'joint goal' and entry['reason'] == ''
    assert entry['stamp'] == f'{stamp.sec}.{stamp.nanosec:09d}'
    # the status travels on its own topic: it may come after the goal status
    client.wait_states(n, ['running', 'idle'], check=graph.check)
    running = [{kv.key: kv.value for kv in st.values} for st in client.statuses[n:] if st.message == 'running']
    assert running and all(v['goal_id'] == goal_id and v['feed'] == '0.01' for v in running)
    assert client.status()['goal_id'] == ''                   # idle: no active goal

    # a refused goal is a goal too: aborted, the reason on /diagnostics
    stamp = client.send_goal(['x_f'], [[0.5e-3]])
    goal_id = client.wait_goal(stamp, ['aborted'], check=graph.check)
    client.wait(lambda: client.goal_entries.get(goal_id, {}).get('status') == 'aborted', 'the reason',
                check=graph.check)
    assert 'outside its stroke' in client.goal_entries[goal_id]['reason']

    # cancel by id: stopped at rest short of the goal, then canceled (at a quarter of the
    # feed, so that the move outlasts two service calls on a loaded machine)
    client.set_feed_override(0.25)
    client.wait(lambda: client.status()['feed_override_setting'] == '0.25', 'setting', check=graph.check)
    stamp = client.send_goal(['x_c'], [[-40e-3]])
    goal_id = client.wait_goal(stamp, ['executing'], check=graph.check)
    assert client.cancel(str(uuid.uuid4())) == (2, [])          # ERROR_UNKNOWN_GOAL_ID
    assert client.cancel(goal_id) == (0, [goal_id])
    client.wait_goal(stamp, ['canceling', 'canceled'], check=graph.check)
    assert client.cancel(goal_id) == (3, [])                     # ERROR_GOAL_TERMINATED
    client.wait(lambda: client.status()['state'] == 'idle', 'idle', check=graph.check)
    assert client.reference()[1][-1][0] > -40e-3 + 1e-3
    client.set_feed_override(1.0)
    client.wait(lambda: client.status()['feed_override_setting'] == '1.0', 'setting', check=graph.check)
    n = len(client.statuses)
    assert client.call('/trajectory/home')[0]
    client.wait_states(n, ['running', 'idle'], check=graph.check)


ROS2 = Path(sys.executable).with_name('ros2')


@pytest.mark.skipif(not ROS2.exists() and shutil.which('ros2') is None,
                    reason='the ros2 command line is not installed (ros2cli)')
def test_a_joint_goal_from_ros2_topic_pub_goes_accepted_executing_succeeded(micromill, graph, client, ros_env):
    from builtin_interfaces.msg import Time
    ros2 = str(ROS2) if ROS2.exists() else shutil.which('ros2')
    stamp = Time(sec=int(time.time()), nanosec=4242)
    goal = (f'{{header: {{stamp: {{sec: {stamp.sec}, nanosec: {stamp.nanosec}}}}}, joint_names: [x_c, y_c], '
            f'points: [{{positions: [0.002, 0.001]}}]}}')
    # --keep-alive: the publisher stays until the reliable delivery is through (its default
    # 0.1 s can end it first on a loaded machine: the goal never arrives)
    result = subprocess.run([ros2, 'topic', 'pub', '--once', '-w', '1', '--max-wait-time-secs', '60', '--keep-alive', '5',
                             contract.JOINT_GOAL.full(), 'trajectory_msgs/msg/JointTrajectory', goal],
                            env=ros_env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    goal_id = client.wait_goal(stamp, ['accepted', 'executing', 'succeeded'], check=graph.check)
    assert client.goal_states[goal_id] == ['accepted', 'executing', 'succeeded']
    client.wait(lambda: abs(client.truth[0] - 0.002) < 2e-6 and abs(client.truth[1] - 0.001) < 2e-6, 'the goal',
                check=graph.check)


def test_the_graph_publishes_its_urdf_with_the_joint_names_of_the_joint_states(micromill, graph, client,
                                                                                tmp_path):
    import xml.etree.ElementTree as ET

    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from machine_ctrl.model import urdf
    description, states = [], []
    client.node.create_subscription(String, contract.ROBOT_DESCRIPTION.name, description.append,
                                    ros_io.qos(contract.ROBOT_DESCRIPTION.qos))
    client.node.create_subscription(JointState, contract.JOINT_STATES.name, states.append, 10)
    client.wait(lambda: description and states, 'robot_description and joint_states', check=graph.check)
    text = description[0].data
    assert ET.fromstring(text).tag == 'robot'
    path = tmp_path / 'published.urdf'
    path.write_text(text)
    assert set(urdf.read_joints(path)) == set(states[0].name) == set(micromill.axis_names)
    check = Path(sys.executable).with_name('check_urdf')
    if check.exists():                                     # urdfdom, as robot_state_publisher parses it
        parsed = subprocess.run([str(check), str(path)], capture_output=True, text=True, timeout=60)
        assert parsed.returncode == 0 and 'Successfully Parsed XML' in parsed.stdout, parsed.stderr


def test_a_fault_refuses_goals_until_hw_sim_is_reset(micromill, graph, client):
    # the graph again, a process per node (the machine starts afresh), to stop one servo
    graph.stop('graph')
    n = len(client.statuses)
    graph.start_nodes(graph_specs(micromill))
    client.wait(lambda: client.states_seen(n, ['idle']) and client.status().get('streamed_to_step', '') != ''
                and int(client.status()['step']) > 0, 'the new graph to step', check=graph.check)
    n = len(client.statuses)
    graph.stop('servo_coarse')                       # hw_sim faults on the missing commands
    client.wait_states(n, ['fault'], check=graph.check)
    assert 'missing command' in client.status()['fault']
    refused = int(client.status()['rejected_goals'])
    client.send_goal(['x_c'], [[1e-3]])
    client.wait(lambda: int(client.status()['rejected_goals']) == refused + 1, 'refusal', check=graph.check)
    assert 'machine is faulted' in client.status()['last_rejection']

    spec = next(s for s in graph_specs(micromill) if s.name == 'servo_coarse')
    graph.start(spec.name, spec.argv())
    graph.wait_for_line('servo_coarse', 'ready', timeout=60)
    # hw_sim's command timeout (5 s) runs from the reset: reset once the new servo has its
    # reference stream (the transient-local history), which may take a while on a busy machine
    client.diagnostics.pop('servo_coarse', None)
    client.wait(lambda: int(client.diagnostics.get('servo_coarse', {}).get('buffered_steps', 0)) > 0,
                'the restarted servo to have its reference', check=graph.check)
    n = len(client.statuses)
    assert client.call('/hw_sim/reset')[0]
    client.wait_states(n, ['idle'], check=graph.check)
    held = client.truth.copy()
    n = len(client.statuses)
    client.send_goal(['x_c'], [[held[0] + 1e-3]])
    client.wait_states(n, ['running', 'idle'], check=graph.check)
    client.wait(lambda: abs(client.truth[0] - held[0] - 1e-3) < 2e-6, 'moving again', check=graph.check)


def started_then_sleeping(flag: str) -> None:
    """A "plan" for the planner process that says it began, then outlasts any test."""
    Path(flag).touch()
    time.sleep(3600.0)


@pytest.fixture
def trajectory_node(micromill, rclpy_context):
    from rclpy.parameter import Parameter

    from machine_ctrl.ros.trajectory_node import TrajectoryNode
    node = TrajectoryNode(context=rclpy_context,
                          parameter_overrides=[Parameter('machine', value=str(micromill.yaml_path))])
    try:
        yield node
    finally:
        node.destroy_node()


def planner_worker(node):
    import multiprocessing
    return next(p for p in multiprocessing.active_children() if p.pid == node.planner_pid)


def test_the_node_stops_its_planner_process_at_once_even_mid_plan(micromill, rclpy_context, tmp_path):
    """destroy_node terminates a plan under way and waits for the planner's pool: no worker
    and no pool thread outlive the node (a pool thread left running raced the interpreter's
    exit hook in a loaded run: OSError EBADF and a traceback at exit)."""
    from rclpy.parameter import Parameter

    from machine_ctrl.ros.trajectory_node import TrajectoryNode
    threads_before = set(threading.enumerate())
    node = TrajectoryNode(context=rclpy_context,
                          parameter_overrides=[Parameter('machine', value=str(micromill.yaml_path))])
    try:
        worker = planner_worker(node)
        flag = tmp_path / 'started'
        node.submit_plan(started_then_sleeping, str(flag))
        wait_until(flag.exists, 'start of the long plan')
    finally:
        node.destroy_node()
    assert not worker.is_alive()
    assert worker.exitcode is not None and worker.exitcode < 0, 'the worker was terminated, not finished'
    assert set(threading.enumerate()) <= threads_before, 'a thread of the planner pool outlived the node'


def test_a_planner_process_that_died_idle_is_restarted_at_the_next_goal(trajectory_node):
    import os
    from concurrent.futures.process import BrokenProcessPool
    node = trajectory_node
    first = node.planner_pid
    worker = planner_worker(node)
    worker.kill()
    worker.join()
    answers = []

    def restarted() -> bool:
        node.submit_plan(os.getpid)
        try:
            answers.append(node.planning.result(timeout=60))
        except BrokenProcessPool:       # submitted before the pool saw its worker die: the next one restarts it
            return False
        return True
    wait_until(restarted, 'restarted planner')
    assert answers[-1] == node.planner_pid != first


def test_the_planner_runs_below_the_nodes_priority(trajectory_node):
    import os

    from trajectory.session import PLANNER_NICENESS
    ours = os.getpriority(os.PRIO_PROCESS, 0)
    assert os.getpriority(os.PRIO_PROCESS, trajectory_node.planner_pid) == min(ours + PLANNER_NICENESS, 19)


def test_stall_limit_is_live_and_refused_beyond_the_lease(trajectory_node):
    """`stall_limit` (contract.STALL_LIMIT): a set reaches the session's stall check at once;
    0 and more than the liveliness lease are refused with the reason, the value kept."""
    from rclpy.parameter import Parameter

    from machine_ctrl import contract
    assert trajectory_node.session.stall_limit == contract.STALL_LIMIT == 3.0
    assert trajectory_node.set_parameters([Parameter('stall_limit', value=5.5)])[0].successful
    assert trajectory_node.session.stall_limit == 5.5
    for bad in (0.0, contract.LIVELINESS_LEASE + 0.5, float('nan')):
        result = trajectory_node.set_parameters([Parameter('stall_limit', value=bad)])[0]
        assert not result.successful and 'stall_limit' in result.reason, (bad, result.reason)
    assert trajectory_node.session.stall_limit == trajectory_node.get_parameter('stall_limit').value == 5.5


def test_stall_limit_at_start_up_is_the_sessions(micromill, rclpy_context):
    from rclpy.parameter import Parameter

    from machine_ctrl.ros.trajectory_node import TrajectoryNode
    node = TrajectoryNode(context=rclpy_context, parameter_overrides=[
        Parameter('machine', value=str(micromill.yaml_path)), Parameter('stall_limit', value=4.5)])
    try:
        assert node.session.stall_limit == 4.5
    finally:
        node.destroy_node()
