"""contour_error_node over real DDS in a lock-step graph (hw_sim + servo_node on trt_5axis,
this test as the reference source): at rest at home, a Ruckig approach to the Eq. (35) path,
its own 0.2 s rest at the start (a corner: the approach arrives in another direction than the
path leaves), the path, the final rest. What the node publishes for every step equals the same
core (machine_ctrl.contour.estimation) run offline on the recorded joint states and the same
reference, with the invalid steps as NaN (README "Contour error", "Validity"); against the
closest-point truth (machine_ctrl.contour.truth) every published number is within its bound,
and the NaN steps are few and sit at the joins; /diagnostics counts them.

Nothing is lost to a slow test reader: the test reports its progress like the recorder
(ros_fixtures.ProgressReporter), so hw_sim never runs far ahead of it, from step 0 on. The test waits on
conditions (a threading.Condition its reader threads notify), never on time; a hang guard
of HANG s only turns a stuck graph into a failure."""
import math
import threading
import time

import numpy as np
import pytest

from machine_ctrl import contract
from machine_ctrl.contour.estimation import ContourEstimator, ToolTrajectory
from machine_ctrl.contour.truth import true_orientation_errors, true_tool_tip_errors
from machine_ctrl.contour.validity import machine_tolerances
from machine_ctrl.ros.graph import NodeSpec
from machine_ctrl.model.kinematics import Kinematics
from ros_fixtures import ProgressReporter
from trajectory.sencer_path import sencer_reference

CHUNK = 500
TAIL = 600            # rest rows after the path; the steps compared end TAIL // 2 before the last row
HANG = 600.0          # s of wall time without the graph finishing: a stuck graph, not a slow one


class Collector:
    """/joint_states, the four contour-error topics by step and the contour node's
    /diagnostics, in a background thread; the newest step held of every stream goes out on
    /recorder/progress; every message notifies `changed`."""

    def __init__(self, node, clock):
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import Vector3Stamped
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64

        self.clock, self.progress = clock, ProgressReporter(node, clock)
        self.changed = threading.Condition()
        qos = QoSProfile(depth=1_000_000, reliability=ReliabilityPolicy.RELIABLE)
        self.states, self.tip, self.orientation = {}, {}, {}
        self.tip_magnitude, self.orientation_magnitude, self.frames = [], [], set()
        self.diagnostics, self.hw_sim = None, {}
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
                                     lambda m: self.on_magnitude(m, self.orientation_magnitude), qos),
            node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, self.on_diagnostics, 100)]
        self.executor = SingleThreadedExecutor(context=node.context)
        self.executor.add_node(node)
        self.running = True
        self.thread = threading.Thread(target=self.spin, daemon=True)
        self.thread.start()

    def spin(self):
        while self.running:
            self.executor.spin_once(timeout_sec=0.05)

    def contour_publishers_matched(self) -> bool:
        return all(s.get_publisher_count() for s in self.subscriptions[1:5])

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

    def on_diagnostics(self, msg):
        for status in msg.status:
            if status.name == 'contour_error':
                self.diagnostics = {kv.key: kv.value for kv in status.values}
            elif status.name == 'hw_sim':
                self.hw_sim = {kv.key: kv.value for kv in status.values}
        self.report()

    def report(self):
        """Progress = the newest step whose state and four contour errors are all here."""
        held = min(len(self.tip_magnitude), len(self.orientation_magnitude)) - 1
        while held > self.held and not all(held in d for d in (self.states, self.tip, self.orientation)):
            held -= 1
        self.held = max(self.held, held)
        self.progress.report(self.held)
        with self.changed:
            self.changed.notify_all()

    def wait(self, condition, what, supervisor):
        """Until condition() holds: woken by every message, and every 0.2 s for what no message
        tells (graph matching, a child that died: supervisor.check())."""
        guard = time.monotonic() + HANG
        with self.changed:
            while not condition():
                supervisor.check()
                assert time.monotonic() < guard, f'the graph hung waiting for {what}'
                self.changed.wait(0.2)

    def stop(self):
        self.running = False
        self.thread.join(timeout=2)
        self.executor.shutdown()


@pytest.fixture(scope='module')
def reference(trt):
    """Rest at home, the approach to the Eq. (35) path (as the trajectory session plays it),
    the path (from its own 0.2 s rest), TAIL rows at rest."""
    from machine_ctrl.model.reference import Reference
    from trajectory import moves
    path = sencer_reference(trt)
    home = np.array(trt.home, float)
    approach = moves.move_to(trt, path.position[0], moves.AxisState.at_rest(home))

    def held(point, steps):
        zeros = np.zeros((steps, len(point)))
        return Reference(path.axis_names, path.period, np.tile(point, (steps, 1)), zeros, zeros)
    return moves.concatenate([held(home, 100), approach, path, held(path.position[-1], TAIL)])


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


def test_node_publishes_the_offline_core_and_marks_the_joins(trt, reference, ros_node, ros_supervisor):
    from sensor_msgs.msg import JointState

    from machine_ctrl.ros import messages as ros_io
    steps = len(reference) - TAIL // 2
    common = {'machine': str(trt.yaml_path)}
    node = ros_node('contour_test')
    collector = Collector(node, ros_io.StepClock.of(trt))
    publish_reference(node, trt, reference)
    specs = [NodeSpec('hw_sim', 'machine_ctrl.ros.hw_sim_node', 'HwSimNode',
                      {**common, 'initial_position': [float(v) for v in reference.position[0]],
                       'min_subscribers': 4,           # servo, contour_error and this test's two readers
                       'recorder_window': ProgressReporter.WINDOW}),   # this test reports its progress
             NodeSpec('servo', 'machine_ctrl.ros.servo_node', 'ServoNode', common),
             NodeSpec('contour_error', 'machine_ctrl.ros.contour_error_node', 'ContourErrorNode',
                      {**common, 'estimator': 'compensated'})]
    try:
        # the contour node first, its four publishers matched with this test's readers and the
        # whole reference in it (its bound looks 200 rows ahead, as the offline core does),
        # before the machine starts: nothing it publishes can go out before this test listens
        contour_spec = specs.pop()
        ros_supervisor.start(contour_spec.name, contour_spec.argv())
        collector.wait(lambda: collector.contour_publishers_matched() and collector.diagnostics is not None
                       and collector.diagnostics['buffered_steps'] == str(len(reference)),
                       'the contour node with the reference', ros_supervisor)
        # hw_sim holds step 0 for this test as for a recorder that has written nothing: it has
        # the test's step -1 before the last state reader it waits for appears (else it could
        # leave step 0 before the test's first report and outrun the writers' queues)
        collector.progress.announce()
        ros_supervisor.start_nodes(specs)
        collector.wait(lambda: collector.hw_sim.get('recorder_step', '') != '', 'hw_sim with this test\'s progress',
                       ros_supervisor)
        collector.subscriptions.append(node.create_subscription(
            JointState, contract.JOINT_STATES.name, lambda _msg: None, 10))     # the last reader hw_sim waits for
        collector.wait(lambda: all(k in collector.tip for k in range(steps))
                       and len(collector.orientation_magnitude) >= steps and len(collector.tip_magnitude) >= steps
                       and all(k in collector.states for k in range(steps)),   # each topic: its own pace
                       f'{steps} contour errors and the states they came from', ros_supervisor)
        # /diagnostics: its counts cover the steps up to estimated_step; wait for one at or past
        # `steps` whose steps are all here
        found = []

        def counted():
            values = collector.diagnostics
            last = int(values['estimated_step'])
            if last >= steps - 1 and all(k in collector.tip and k in collector.orientation for k in range(last + 1)):
                found.append(values)
            return bool(found)
        collector.wait(counted, 'the diagnostics of the last step', ros_supervisor)
        diagnostics = found[0]
    finally:
        ros_supervisor.stop_all()
        collector.stop()

    # the same core offline, on the recorded joint states
    kinematics = Kinematics.from_config(trt)
    trajectory = ToolTrajectory.from_reference(kinematics, reference)
    estimator = ContourEstimator(kinematics, 'compensated', machine_tolerances(trt))
    offline = [estimator.update(trajectory, k, collector.states[k]) for k in range(steps)]
    tip = np.array([collector.tip[k] for k in range(steps)])
    orientation = np.array([collector.orientation[k] for k in range(steps)])
    for live, part, magnitudes in ((tip, 'tool_tip', collector.tip_magnitude),
                                   (orientation, 'orientation', collector.orientation_magnitude)):
        estimates = [getattr(e, part) for e in offline]
        valid = np.array([e.valid for e in estimates])
        expected = np.array([e.vector if e.valid else [math.nan] * 3 for e in estimates])
        assert np.array_equal(live, expected, equal_nan=True)
        assert np.array_equal(magnitudes[:steps], [math.sqrt(sum(v * v for v in e.vector)) if e.valid else math.nan
                                                   for e in estimates], equal_nan=True)
        assert np.isnan(live[~valid]).all() and np.isfinite(live[valid]).all()
    assert collector.frames == {'workpiece'}
    assert np.nanmax(np.linalg.norm(tip, axis=1)) > 1e-5       # the machine moved and made contour errors

    # against the closest-point truth: every number within its bound; NaN few and at the joins
    poses = [kinematics.forward(collector.states[k]) for k in range(steps)]
    truth = {'tool_tip': true_tool_tip_errors(trajectory, np.array([x[0] for x in poses])),
             'orientation': true_orientation_errors(trajectory, np.array([x[1] for x in poses]))}
    moving = trajectory.geometry[0].moving[:steps]
    joins = np.flatnonzero(np.diff(moving.astype(int))) + 1    # approach start, its end, the path's start, end
    assert len(joins) == 4
    streams = {'tool_tip': collector.tip, 'orientation': collector.orientation}
    for live, part in ((tip, 'tool_tip'), (orientation, 'orientation')):
        bound = np.array([getattr(e, part).check.bound for e in offline])
        published = ~np.isnan(live[:, 0])
        deviation = np.linalg.norm(live - truth[part], axis=1)
        assert (deviation[published] <= bound[published]).all()
        nan_steps = np.flatnonzero(~published)
        # the last steps of the approach (0.46 mm off there), the 200-step rest at the corner after
        # it (while the tool is on the side of the path leaving it) and 20 steps into the path,
        # the last 20 of the path; a few orientation steps early in the approach, where its error
        # is small against the turn of the tool axis (offline: 191 tool-tip, 224 orientation steps)
        at_joins = np.array([any(j - 30 <= k <= j + 40 for j in joins) or joins[1] <= k <= joins[2]
                             for k in nan_steps], bool)
        assert at_joins.all(), nan_steps[~at_joins]
        assert len(nan_steps) < 0.04 * steps, len(nan_steps)
        last = int(diagnostics['estimated_step'])
        assert int(diagnostics[f'invalid_{part}_steps']) == sum(math.isnan(streams[part][k][0]) for k in range(last + 1))
    # the approach's end: the estimate 0.46 mm off the truth, published as NaN
    offline_tip = np.array([e.tool_tip.vector for e in offline])
    jump = np.linalg.norm(offline_tip - truth['tool_tip'], axis=1) > 1e-4
    assert jump.any() and np.isnan(tip[jump]).all()


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


def test_a_state_far_ahead_is_held_back_until_its_next_step_follows_or_it_comes_again():
    from machine_ctrl.ros.contour_error_node import PendingStates
    refused = []
    pending = PendingStates(history=100, warn=lambda _: None, info=lambda _: None, refuse=refused.append)
    assert pending.add(500, [0.0])               # the first state wherever it is (started mid-run)
    assert pending.add(501, [0.0])
    assert not pending.add(10_000_000, [0.0])    # a stray stamp from the future: held back ...
    assert pending.add(502, [0.0]) and pending.last_step == 502     # ... and the real states go on
    assert refused == ['state of step 10000000 skips ahead of step 502 (not followed by step 10000001, '
                       'nor sent again)']
    assert not pending.add(510, [1.0])           # states lost on the way (a queue overrun) ...
    assert pending.add(511, [2.0])               # ... taken with its successor, without a word
    assert not pending.add(520, [3.0])
    assert pending.add(520, [3.0])               # or when it comes again
    assert [(s, q[0]) for s, q in pending.queue][-4:] == [(502, 0.0), (510, 1.0), (511, 2.0), (520, 3.0)]
    assert pending.last_step == 520 and len(refused) == 1
