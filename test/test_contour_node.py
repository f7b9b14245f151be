"""contour_error_node over real DDS in a lock-step graph (hw_sim + servo_node on trt_5axis,
this test as the reference source playing the Eq. (35) path): what it publishes for every
step equals the same core (machine_ctrl.contour.estimation) run offline on the recorded joint states
and the same reference.

Nothing is lost to a slow test reader: the test reports its progress like the recorder
(ros_fixtures.ProgressReporter), so hw_sim never runs far ahead of it."""
import math
import threading
import time

import numpy as np
import pytest

from machine_ctrl import contract
from machine_ctrl.contour.estimation import ContourEstimator, ToolTrajectory
from machine_ctrl.ros.graph import NodeSpec
from machine_ctrl.model.kinematics import Kinematics
from ros_fixtures import ProgressReporter
from trajectory.sencer_path import sencer_reference

STEPS = 1200          # 0.2 s at rest, then 1 s of the path
CHUNK = 500


class Collector:
    """/joint_states and the four contour-error topics by step, in a background thread; the
    newest step held of every stream goes out on /recorder/progress."""

    def __init__(self, node, clock):
        from geometry_msgs.msg import Vector3Stamped
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64

        self.clock, self.progress = clock, ProgressReporter(node, clock)
        qos = QoSProfile(depth=1_000_000, reliability=ReliabilityPolicy.RELIABLE)
        self.states, self.tip, self.orientation = {}, {}, {}
        self.tip_magnitude, self.orientation_magnitude, self.frames = [], [], set()
        self.held = -1
        self.subscriptions = [
            node.create_subscription(JointState, contract.JOINT_STATES.name, self.on_state, qos),
            node.create_subscription(Vector3Stamped, contract.CONTOUR_TOOL_TIP.name,
                                     lambda m: self.on_vector(m, self.tip), qos),
            node.create_subscription(Vector3Stamped, contract.CONTOUR_ORIENTATION.name,
                                     lambda m: self.on_vector(m, self.orientation), qos),
            node.create_subscription(Float64, contract.CONTOUR_TOOL_TIP_MAGNITUDE.name,
                                     lambda m: self.on_magnitude(m, self.tip_magnitude), qos),
            node.create_subscription(Float64, contract.CONTOUR_ORIENTATION_MAGNITUDE.name,
                                     lambda m: self.on_magnitude(m, self.orientation_magnitude), qos)]
        self.executor = SingleThreadedExecutor(context=node.context)
        self.executor.add_node(node)
        self.running = True
        self.thread = threading.Thread(target=self.spin, daemon=True)
        self.thread.start()

    def spin(self):
        while self.running:
            self.executor.spin_once(timeout_sec=0.05)

    def contour_publishers_matched(self) -> bool:
        return all(s.get_publisher_count() for s in self.subscriptions[1:])

    def on_state(self, msg):
        self.states[self.clock.step(msg.header.stamp)] = msg.position.tolist()
        self.report()

    def on_vector(self, msg, store):
        self.frames.add(msg.header.frame_id)
        store[self.clock.step(msg.header.stamp)] = [msg.vector.x, msg.vector.y, msg.vector.z]
        self.report()

    def on_magnitude(self, msg, store):
        store.append(msg.data)
        self.report()

    def report(self):
        """Progress = the newest step whose state and four contour errors are all here."""
        held = min(len(self.tip_magnitude), len(self.orientation_magnitude)) - 1
        while held > self.held and not all(held in d for d in (self.states, self.tip, self.orientation)):
            held -= 1
        self.held = max(self.held, held)
        self.progress.report(self.held)

    def stop(self):
        self.running = False
        self.thread.join(timeout=2)
        self.executor.shutdown()


@pytest.fixture(scope='module')
def reference(trt):
    return sencer_reference(trt)


def publish_reference(node, machine, reference):
    from trajectory_msgs.msg import JointTrajectory

    from machine_ctrl.ros import messages as ros_io
    clock = ros_io.StepClock.of(machine)
    pub = node.create_publisher(JointTrajectory, contract.REFERENCE.name, ros_io.REFERENCE_QOS)
    for first in range(0, len(reference), CHUNK):
        rows = slice(first, first + CHUNK)
        pub.publish(ros_io.trajectory_chunk(clock, first, machine.axis_names, reference.position[rows],
                                            reference.velocity[rows], reference.acceleration[rows]))
    return pub


def test_node_publishes_what_the_offline_core_computes(trt, reference, ros_node, ros_supervisor):
    from machine_ctrl.ros import messages as ros_io
    common = {'machine': str(trt.yaml_path)}
    node = ros_node('contour_test')
    collector = Collector(node, ros_io.StepClock.of(trt))
    publish_reference(node, trt, reference)
    specs = [NodeSpec('hw_sim', 'machine_ctrl.ros.hw_sim_node', 'HwSimNode',
                      {**common, 'initial_position': [float(v) for v in reference.position[0]],
                       'min_subscribers': 3,           # servo, contour_error and this test
                       'recorder_window': ProgressReporter.WINDOW}),   # this test reports its progress
             NodeSpec('servo', 'machine_ctrl.ros.servo_node', 'ServoNode', common),
             NodeSpec('contour_error', 'machine_ctrl.ros.contour_error_node', 'ContourErrorNode',
                      {**common, 'estimator': 'compensated'})]
    try:
        # the contour node first, and its four publishers matched with this test's readers,
        # before the machine starts: nothing it publishes can go out before this test listens
        contour_spec = specs.pop()
        ros_supervisor.start(contour_spec.name, contour_spec.argv())
        deadline = time.monotonic() + 120
        while not collector.contour_publishers_matched():
            assert time.monotonic() < deadline, 'contour_error publishers not matched'
            ros_supervisor.check()
            time.sleep(0.1)
        ros_supervisor.start_nodes(specs)
        deadline = time.monotonic() + 120
        while not all(k in collector.tip for k in range(STEPS)) or len(collector.orientation_magnitude) < STEPS:
            assert time.monotonic() < deadline, f'got {len(collector.tip)} contour errors'
            ros_supervisor.check()
            time.sleep(0.1)
    finally:
        ros_supervisor.stop_all()
        collector.stop()

    kinematics = Kinematics.from_config(trt)
    trajectory = ToolTrajectory.from_reference(kinematics, reference)
    estimator = ContourEstimator(kinematics, 'compensated')
    offline = [estimator.update(trajectory, k, collector.states[k]) for k in range(STEPS)]
    tip = np.array([collector.tip[k] for k in range(STEPS)])
    orientation = np.array([collector.orientation[k] for k in range(STEPS)])
    assert np.array_equal(tip, np.array([e.tool_tip.vector for e in offline]))
    assert np.array_equal(orientation, np.array([e.orientation for e in offline]))
    assert collector.tip_magnitude[:STEPS] == [math.sqrt(sum(v * v for v in e.tool_tip.vector)) for e in offline]
    assert collector.orientation_magnitude[:STEPS] == [math.sqrt(sum(v * v for v in e.orientation))
                                                      for e in offline]
    assert collector.frames == {'workpiece'}
    assert np.linalg.norm(tip, axis=1).max() > 1e-5       # the machine moved and made contour errors


# --- states without a reference row: a state of the node, not a flood ------------------------------

def rows_from(trajectory, first, count):
    zeros = np.zeros((count, 3))
    trajectory.add(first, zeros, zeros, zeros, zeros, zeros)


def test_states_before_the_reference_are_start_up_and_a_gap_is_warned_once():
    from machine_ctrl.ros.contour_error_node import PendingStates
    warned, told = [], []
    pending = PendingStates(history=10, warn=warned.append, info=told.append)
    trajectory = ToolTrajectory(1e-3)
    assert pending.state() == 'waiting for states'
    for step in range(25):                       # hw_sim steps before the reference source streams
        assert pending.add(step, [0.0])
    assert not pending.add(24, [0.0]) and len(pending) == 10       # a re-send is not taken again
    assert pending.state() == 'waiting for the reference (never received)'
    assert list(pending.ready(trajectory)) == [] and pending.before_reference == 15
    rows_from(trajectory, 20, 100)               # the reference begins at step 20
    pending.reference_from(20)
    assert [step for step, _ in pending.ready(trajectory)] == list(range(20, 25))
    assert (pending.before_reference, pending.skipped, pending.gaps, pending.state()) == (20, 0, 0, 'ok')
    assert warned == [] and told == ['20 states came before the reference began (step 20): start-up, '
                                     'no contour error for them']
    for step in range(25, 120):
        pending.add(step, [0.0])
        list(pending.ready(trajectory))
    for step in range(120, 135):                 # the stream stops at 119: a gap
        pending.add(step, [0.0])
        assert list(pending.ready(trajectory)) == []
    assert (pending.skipped, pending.gaps, pending.gap_since) == (5, 1, 120)
    assert pending.state() == 'no reference since step 120 (5 steps without it so far)'
    assert warned == ['no reference row for step 120 (waited 10 steps for it): its contour error is not '
                      f'published; one line per gap, counted as skipped_steps on {contract.DIAGNOSTICS.name}']
    rows_from(trajectory, 130, 100)              # rows again, from step 130
    assert [step for step, _ in pending.ready(trajectory)] == list(range(130, 135))
    assert (pending.skipped, pending.gaps, pending.gap_since, pending.state()) == (10, 1, None, 'ok')
    assert len(warned) == 1 and told[-1] == ('reference rows back from step 130: 10 steps from step 120 on had '
                                             'none (no contour error published for them)')
