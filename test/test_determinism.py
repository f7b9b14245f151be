"""Determinism, proven on recorded bags: one tool-path goal (a half circle of 12 points from
the home tool tip, sent with `machine-ctrl send` as a CSV file) run three ways —

(a) `machine-ctrl bringup --record` (a process per node, real DDS),
(b) `machine-ctrl bringup --single-process --record`,
(c) offline, no ROS (machine_ctrl/ros/run_bag.write_goal_bag: the trajectory node's own
    session streams the reference, hw_sim.offline runs the machine) —

gives bit-identical /joint_states (position, velocity, effort and stamps, every recorded
step from step 0), /servo_commands, /dual_stage/offsets and /reference rows.

What is and is not a function of the goal alone. The trajectory node plans a path in a
worker process while the graph keeps stepping (it streams the held position
`lookahead_steps` ahead), and starts the motion at the first row not yet streamed when the
plan is in. That step (`motion_start_step` on /trajectory/status, recorded in the bag) is
therefore a chunk boundary >= lookahead_steps that depends on the wall time planning took
against the graph's speed: it legitimately differs between runs (README "Node graph":
"goals take effect at a step that depends on planning and message timing"). And the runs
cannot be compared from their start steps instead: sensor and actuator noise are seeded
streams drawn once per absolute step, so the machine is in a slightly different state at
step 3000 than at step 3500 (the noise-driven hold jitter), and the motion from there
differs by far more than a bit. So the proof is: everything before the motion is the same
in every run (the hold of the measured step-0 position), and given the start step the
graph reports, the whole bag — from step 0 on, hold, approach, path and hold after — is
bit-identical to the offline run of the same goal with that start step; when two graph
runs start at the same step they equal each other bit for bit (compared directly too).

The expected values are nobody's computation alone: three independent executions (two
graphs over DDS in different process layouts, one plain loop) must agree exactly.
"""
import math
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from machine_ctrl import contract, parameters
from machine_ctrl.app.processes import Supervisor
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.recording.bag import Bag
from trajectory import toolpath

EXE = str(Path(sys.executable).with_name('machine-ctrl'))
POINTS, RADIUS = 12, 0.5e-3           # a half circle: 1.6 mm at the 10 mm/s feed, ~1800 steps


@pytest.fixture(scope='module')
def path_csv(micromill, tmp_path_factory):
    """The goal: a half circle of tool tips from the tool tip at hw_sim's start (home),
    tool axis +z, as a CSV file (exact floats: repr)."""
    tip, _ = Kinematics.from_config(micromill).forward(np.array(micromill.home, float))
    th = np.linspace(0.0, math.pi, POINTS)
    p = np.column_stack([tip[0] + RADIUS * (np.cos(th) - 1), tip[1] + RADIUS * np.sin(th), np.full(POINTS, tip[2])])
    path = tmp_path_factory.mktemp('goal') / 'half_circle.csv'
    lines = ['px,py,pz,oi,oj,ok'] + [','.join(repr(float(v)) for v in (*pi, 0.0, 0.0, 1.0)) for pi in p]
    path.write_text('\n'.join(lines) + '\n')
    return path


def deserialize(data, type_):
    from rclpy.serialization import deserialize_message
    return deserialize_message(data, type_)


class Recorded:
    """The per-step topics of a bag, decoded with rclpy's own types, by control step."""

    def __init__(self, bag_dir, machine):
        from diagnostic_msgs.msg import DiagnosticStatus
        from geometry_msgs.msg import PointStamped
        from sensor_msgs.msg import JointState
        from trajectory_msgs.msg import JointTrajectory

        from machine_ctrl.ros import messages as ros_io
        clock = ros_io.StepClock.of(machine)
        period_ns = round(machine.control_period * 1e9)

        def nanoseconds(stamp):
            return stamp.sec * 1_000_000_000 + stamp.nanosec

        def step(stamp):
            ns = nanoseconds(stamp)
            assert ns % period_ns == 0, f'stamp {ns} ns off the control grid'
            return ns // period_ns

        self.states, self.commands, self.offsets, self.reference, self.tracker = {}, {}, {}, {}, {}
        self.start_steps = set()
        per_step = {contract.JOINT_STATES.full(): self.states, contract.DUAL_STAGE_OFFSETS.full(): self.offsets}
        wanted = [topic.full() for topic in (contract.JOINT_STATES, contract.SERVO_COMMANDS, contract.DUAL_STAGE_OFFSETS,
                                             contract.REFERENCE, contract.TRAJECTORY_STATUS, contract.TRACKER)]
        with Bag(bag_dir) as bag:
            self.topics = set(bag.topics)
            for message in bag.messages(wanted):
                if message.topic in per_step or message.topic == contract.SERVO_COMMANDS.full():
                    msg = deserialize(message.data, JointState)
                    k = step(msg.header.stamp)
                    value = (nanoseconds(msg.header.stamp), tuple(msg.name), tuple(msg.position), tuple(msg.velocity),
                             tuple(msg.effort))
                    table, key = ((self.commands, (k, tuple(msg.name))) if message.topic == contract.SERVO_COMMANDS.full()
                                  else (per_step[message.topic], k))
                    # a re-sent message (lock-step re-send) must repeat the first exactly
                    assert table.setdefault(key, value) == value, f'{message.topic} step {k} re-sent differently'
                elif message.topic == contract.REFERENCE.full():
                    msg = deserialize(message.data, JointTrajectory)
                    first = step(msg.header.stamp)
                    for i, point in enumerate(msg.points):      # a later chunk replaces rows from its first
                        self.reference[first + i] = (tuple(point.positions), tuple(point.velocities),
                                                     tuple(point.accelerations))
                elif message.topic == contract.TRACKER.full():
                    # what dual_stage takes: a rogue publisher's refused readings (test_robot_piezo_graph's)
                    # may be in the bag too, when the recorder's reader was matched before they came
                    msg = deserialize(message.data, PointStamped)
                    try:
                        k = clock.step(msg.header.stamp)
                        value = ros_io.tracker_reading(msg, machine.workpiece_frame)
                    except ros_io.InvalidMessage:
                        continue
                    assert self.tracker.setdefault(k, value) == value, f'tracker step {k} re-sent differently'
                elif message.topic == contract.TRAJECTORY_STATUS.full():
                    status = deserialize(message.data, DiagnosticStatus)
                    values = {kv.key: kv.value for kv in status.values}
                    if status.message == 'running' and values.get('motion_start_step'):
                        self.start_steps.add(int(values['motion_start_step']))
        self.steps = len(self.states)
        assert sorted(self.states) == list(range(self.steps)), 'a /joint_states step is missing'

    @property
    def start_step(self) -> int:
        assert len(self.start_steps) == 1, self.start_steps
        return next(iter(self.start_steps))

    def joint_states(self, steps: int):
        """(stamps in ns, positions, velocities, efforts) of steps 0..steps-1, as arrays."""
        rows = [self.states[k] for k in range(steps)]
        return tuple(np.array([r[i] for r in rows]) for i in (0, 2, 3, 4))

    def names(self):
        return {self.states[k][1] for k in self.states}


def run_graph(micromill, ros_env, log_dir, bag, csv, single_process) -> Recorded:
    """bringup --record [--single-process], send the goal, stop (exit 0 each); the bag."""
    argv = [EXE, 'bringup', '--record', str(bag)] + (['--single-process'] if single_process else [])
    times = [time.monotonic()]
    with Supervisor(ros_env, log_dir=log_dir, stop_timeout=3.0) as supervisor:
        child = supervisor.start('bringup', argv)
        supervisor.wait_for_line('bringup', 'all nodes ready', timeout=180)
        times.append(time.monotonic())
        sent = subprocess.run([EXE, 'send', str(csv)], env=ros_env, capture_output=True, text=True, timeout=600)
        assert sent.returncode == 0, sent.stdout + sent.stderr          # the goal succeeded
        assert 'succeeded' in sent.stdout
        times.append(time.monotonic())
        child.signal_group(signal.SIGINT)
        assert supervisor.wait('bringup', timeout=180) == 0, '\n'.join(child.tail(40))
        times.append(time.monotonic())
    recorded = Recorded(bag, micromill)
    times.append(time.monotonic())
    print(f'{argv[1:]}: up {times[1] - times[0]:.1f} s, goal {times[2] - times[1]:.1f} s, stop '
          f'{times[3] - times[2]:.1f} s, bag read {times[4] - times[3]:.1f} s; motion from step '
          f'{recorded.start_step}, {recorded.steps} steps recorded')
    return recorded


@pytest.fixture(scope='module')
def graph_runs(micromill, ros_env, path_csv, tmp_path_factory):
    runs = {}
    for mode, single in (('process per node', False), ('single process', True)):
        where = tmp_path_factory.mktemp('single' if single else 'multi')
        runs[mode] = run_graph(micromill, ros_env, where / 'logs', where / 'bag', path_csv, single)
    return runs


@pytest.fixture(scope='module')
def offline_runs(micromill, graph_runs, path_csv, tmp_path_factory):
    """(c): for each graph run, the offline run of the goal from the start step that run
    reports, over the steps it recorded, written as a bag and read back."""
    from machine_ctrl.ros.run_bag import write_goal_bag
    runs = {}
    for mode, graph in graph_runs.items():
        bag = tmp_path_factory.mktemp('offline') / 'bag'
        run, _ = write_goal_bag(bag, micromill, toolpath.read_csv(path_csv), start_step=graph.start_step,
                                steps=graph.steps)
        assert run.goal_state == 'succeeded' and run.motion_start == graph.start_step
        runs[mode] = (run, Recorded(bag, micromill))
    return runs


def assert_joint_states_equal(a: Recorded, b: Recorded, steps: int):
    for name, x, y in zip(('stamps', 'position', 'velocity', 'effort'), a.joint_states(steps), b.joint_states(steps)):
        assert x.shape == y.shape and np.array_equal(x, y), (
            f'/joint_states {name} differ first at step {int(np.flatnonzero((x != y).reshape(len(x), -1).any(axis=1))[0])}'
            if x.shape == y.shape else f'/joint_states {name} shapes {x.shape} {y.shape}')


def assert_per_step_topics_equal(a: Recorded, b: Recorded, steps: int):
    """/servo_commands, /dual_stage/offsets (the answers to the states of steps 0..steps-2:
    the last state a graph published may go unanswered when it is stopped), /reference
    (rows 0..steps-1) and, on a machine with a tracker, /hw_sim/tracker (steps 0..steps-1)."""
    assert a.names() == b.names()
    assert bool(a.tracker) == bool(b.tracker)
    for topic, x, y, upto in (('/servo_commands', a.commands, b.commands, steps - 1),
                              ('/dual_stage/offsets', a.offsets, b.offsets, steps - 1),
                              ('/reference', a.reference, b.reference, steps),
                              ('/hw_sim/tracker', a.tracker, b.tracker, steps)):
        if topic == '/hw_sim/tracker' and not a.tracker:
            continue
        keys = sorted(key for key in x if (key[0] if isinstance(key, tuple) else key) < upto)
        assert keys, topic
        other = sorted(key for key in y if (key[0] if isinstance(key, tuple) else key) < upto)
        assert keys == other, (f'{topic}: only in the first run {sorted(set(keys) - set(other))[:10]}, '
                               f'only in the second {sorted(set(other) - set(keys))[:10]}')
        different = [key for key in keys if x[key] != y[key]]     # tuples of floats: exact
        assert not different, f'{topic}: {len(different)} of {len(keys)} differ, first {different[0]}'


@pytest.mark.parametrize('mode', ['process per node', 'single process'])
def test_a_graph_run_equals_the_offline_run_bit_for_bit(micromill, graph_runs, offline_runs, mode):
    """Every recorded step, from step 0 (the hold) through the approach and the path to the
    hold after it, equals the offline run of the same goal with the start step the graph
    reported: /joint_states, each servo's /servo_commands, /dual_stage/offsets and the
    /reference rows the trajectory node streamed."""
    graph = graph_runs[mode]
    run, offline = offline_runs[mode]
    assert offline.steps == graph.steps > run.motion_end       # the whole motion was recorded
    assert graph.topics >= offline.topics                      # the graph records every offline topic
    assert_joint_states_equal(graph, offline, graph.steps)
    assert_per_step_topics_equal(graph, offline, graph.steps)

    _, position, velocity, _ = graph.joint_states(graph.steps)
    # the machine moved: the measured tool tip (forward kinematics) spans the half circle,
    # 2 R in x and R in y, at about the 10 mm/s feed, and stood still before the motion
    kinematics = Kinematics.from_config(micromill)
    tips = np.array([kinematics.forward(q)[0] for q in position[::10]])
    np.testing.assert_allclose(np.ptp(tips, axis=0)[:2], [2 * RADIUS, RADIUS], atol=5e-6)
    x = micromill.axis_names.index('x_c')
    assert np.abs(velocity[run.motion_start:run.motion_end, x]).max() > 5e-3
    linear = [a.unit == 'm' for a in micromill.axes]    # (the table tilts jitter by ~20 urad: force noise)
    assert np.abs(position[:run.motion_start, linear] - position[0, linear]).max() < 1e-6


def test_process_per_node_and_single_process_agree(micromill, graph_runs):
    """The two process layouts directly: the same until either motion starts, and the same
    throughout when they start at the same step (module docstring: the start step is a
    matter of planning time, not of the layout)."""
    a, b = graph_runs['process per node'], graph_runs['single process']
    print(f'motion start steps: process per node {a.start_step}, single process {b.start_step}; '
          f'recorded steps {a.steps}, {b.steps}')
    same = a.start_step == b.start_step
    steps = min(a.steps, b.steps) if same else min(a.start_step, b.start_step)
    assert_joint_states_equal(a, b, steps)
    assert_per_step_topics_equal(a, b, steps)


def test_runs_cannot_be_compared_from_their_start_steps_instead(micromill, path_csv):
    """Why the proof needs the start step (module docstring): offline, the same goal started
    one chunk later holds the same before either start, but from its own start on it is not
    the first run shifted — the noise streams are drawn per absolute step."""
    from hw_sim.offline_goal import earliest_start, run_goal
    from machine_ctrl.ros.run_bag import as_received
    cl = as_received(micromill, toolpath.read_csv(path_csv))
    early, chunk = earliest_start(), parameters.TRAJECTORY.spec('chunk_steps').default
    first = run_goal(micromill, cl, start_step=early)
    later = run_goal(micromill, cl, start_step=early + chunk)
    assert np.array_equal(first.record.measured[:early], later.record.measured[:early])
    motion = first.motion_end - first.motion_start
    assert later.motion_end - later.motion_start == motion            # the same planned motion ...
    assert np.array_equal(first.reference.position[early:early + motion],
                          later.reference.position[early + chunk:early + chunk + motion])   # ... streamed alike
    ours = first.record.measured[early:early + motion]
    shifted = later.record.measured[early + chunk:early + chunk + motion]
    assert not np.array_equal(ours, shifted)
    with pytest.raises(ValueError, match='multiple of chunk_steps'):
        run_goal(micromill, cl, start_step=early + 1)
