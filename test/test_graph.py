"""The lock-step node graph over real DDS: hw_sim, servo nodes, dual_stage and the
reference source, as separate processes and all in one process, against the offline
runner (design.md "Time": same config, same input -> bit-identical states)."""
import sys
import threading
import time

import numpy as np
import pytest

from machine_ctrl import contract
from machine_ctrl.ros.graph import NodeSpec, default_graph
from hw_sim.offline import run
from ros_fixtures import ProgressReporter
from trajectory.contours import circle

STEPS = 2000


class StateRecorder:
    """Collects /joint_states by step in a background executor thread, reporting its
    progress to hw_sim (ros_fixtures.ProgressReporter: the graph never outruns it)."""

    def __init__(self, node, machine):
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState

        from machine_ctrl.ros import messages as ros_io
        self.clock = ros_io.StepClock.of(machine)
        self.progress = ProgressReporter(node, self.clock)
        self.rows, self.next_step = {}, 0
        # deep reader queue: the graph may outrun this thread for a while, and a keep-last
        # reader overwrites what it has not taken yet
        qos = QoSProfile(depth=1_000_000, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(JointState, contract.JOINT_STATES.name, self.on_state, qos)
        self.executor = SingleThreadedExecutor(context=node.context)
        self.executor.add_node(node)
        self.thread = threading.Thread(target=self.spin, daemon=True)
        self.running = True
        self.thread.start()

    def spin(self):
        while self.running:
            self.executor.spin_once(timeout_sec=0.05)

    def on_state(self, msg):
        self.rows[self.clock.step(msg.header.stamp)] = (msg.position.tolist(), msg.velocity.tolist(),
                                                        msg.effort.tolist())
        while self.next_step in self.rows:
            self.next_step += 1
        self.progress.report(self.next_step - 1)

    def wait_for(self, steps, timeout, supervisor):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if sum(1 for k in list(self.rows) if k < steps) == steps:   # list(): the spin thread adds
                return
            supervisor.check()
            time.sleep(0.1)
        raise AssertionError(f'got {len(self.rows)} states, last step {max(list(self.rows), default=None)}')

    def stop(self):
        self.running = False
        self.thread.join(timeout=2)
        self.executor.shutdown()

    def arrays(self, steps):
        rows = [self.rows[k] for k in range(steps)]
        return tuple(np.array([r[i] for r in rows]) for i in range(3))


@pytest.fixture(scope='module')
def offline(micromill):
    reference, _ = circle(micromill)
    return run(micromill, reference, steps=STEPS)


def record_graph(micromill, ros_node, ros_supervisor, single_process, contour='circle', during=None,
                 overrides=None):
    """The first STEPS states of the graph; `during()` runs once the nodes are started;
    `overrides`: {node name: parameters over its defaults} (a process per node only)."""
    recorder = StateRecorder(ros_node('recorder'), micromill)
    window = ProgressReporter.WINDOW
    try:
        # hw_sim holds step 0 until servo_coarse, servo_fine, dual_stage and this recorder
        # all subscribe /joint_states, so the recorder sees every step, and then runs at most
        # `window` steps ahead of it
        if single_process:
            ros_supervisor.start('graph', [sys.executable, '-m', 'machine_ctrl.ros.graph', '--machine',
                                           str(micromill.yaml_path), '--hw-sim', 'min_subscribers=4',
                                           '--hw-sim', f'recorder_window={window}'])
        else:
            specs = default_graph(micromill, contour, hw_sim={'min_subscribers': 4, 'recorder_window': window})
            overrides = overrides or {}
            ros_supervisor.start_nodes([NodeSpec(s.name, s.module, s.cls, {**s.parameters, **overrides[s.name]})
                                        if s.name in overrides else s for s in specs])
        if during is not None:
            during()
        recorder.wait_for(STEPS, timeout=120, supervisor=ros_supervisor)
    finally:
        ros_supervisor.stop_all()
        recorder.stop()
    return recorder.arrays(STEPS)


def assert_bit_identical(graph, offline):
    position, velocity, effort = graph
    assert np.array_equal(position, offline.measured)
    assert np.array_equal(velocity, offline.measured_velocity)
    assert np.array_equal(effort, offline.effort)
    assert np.ptp(position[:, 0]) > 1e-4          # the circle did move the machine


def test_multi_process_graph_equals_offline_runner(micromill, offline, ros_node, ros_supervisor):
    assert_bit_identical(record_graph(micromill, ros_node, ros_supervisor, single_process=False), offline)


def test_single_process_graph_equals_offline_runner(micromill, offline, ros_node, ros_supervisor):
    """Its per-step streams between its nodes through the local bus (machine_ctrl.ros.local_bus):
    /servo_commands and the offsets only there, /joint_states there and, for this test's
    reader, through DDS too."""
    assert_bit_identical(record_graph(micromill, ros_node, ros_supervisor, single_process=True), offline)
    # hw_sim's commands, servo_coarse's, servo_fine's and dual_stage's states, servo_fine's offsets
    assert 'local bus: 5 readers of the per-step streams' in ros_supervisor['graph'].log_path.read_text()


def test_the_contour_control_in_servo_fine_equals_the_offline_runner(micromill, ros_node, ros_supervisor):
    """[7/8] part 2: servo_fine holds x_f y_f z_f, the coupled axes, takes the whole /reference
    in chunks and estimates each step's contour error itself; the states are those of the
    offline runner with the contour control on, bit for bit (contour_coupling.py: the tool rows
    an estimate sees depend on the step alone), and not those without it."""
    reference, _ = circle(micromill)
    coupled = run(micromill, reference, steps=STEPS, contour_control=True)
    assert not np.array_equal(coupled.measured, run(micromill, reference, steps=STEPS).measured)
    assert_bit_identical(record_graph(micromill, ros_node, ros_supervisor, single_process=False,
                                      overrides={'servo_fine': {'contour_control': True}}), coupled)


def test_servo_nodes_with_a_belief_file_equal_the_offline_runner_with_it(micromill, offline, ros_node, ros_supervisor,
                                                                          tmp_path):
    """[8/8]: the servo nodes' `belief` (machine-ctrl identify --out files) changes the laws'
    values while hw_sim keeps the machine's plant: the states are the offline runner's with
    the same belief, bit for bit, and not the nominal run's."""
    from machine_ctrl.model.config import load_machine
    belief = tmp_path / 'x_c.yaml'
    belief.write_text('axes:\n  x_c:\n    drive: {mass: 22.5, damping: 30.0}\n    control:\n'
                      '      lugre_feedforward: {static: 32.5, coulomb: 33.0, stribeck_velocity: 0.04}\n')
    reference, _ = circle(micromill)
    expected = run(load_machine(micromill.yaml_path, belief=[belief]), reference, steps=STEPS)
    assert not np.array_equal(expected.effort, offline.effort)
    servo = {'belief': [str(belief)]}
    assert_bit_identical(record_graph(micromill, ros_node, ros_supervisor, single_process=False,
                                      overrides={'servo_coarse': servo, 'servo_fine': servo}), expected)


def test_the_fts_lathe_graph_at_199_6_khz_with_its_acceleration_loop_equals_the_offline_runner(
        fts_lathe, ros_node, ros_supervisor, tmp_path):
    """Ding's lathe (issue [3/8]) as a process per node at its 5010 ns period, holding home
    with every noise source on (seeded), W's PID with the acceleration loop of Fig. 7-6
    (K_a = 4, section 7.5.3): servo_fine reads the accelerometer from /accelerometers step by
    step; the same states and commands as the offline runner, bit for bit. Rogue readings on
    /accelerometers (a frame no accelerometer has, NaN, a stamp off the control grid) are
    refused with their reason on servo_fine's /diagnostics and change nothing."""
    import shutil

    from builtin_interfaces.msg import Time
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import Imu

    from machine_ctrl.model.config import load_machine
    from machine_ctrl.model.reference import Reference
    from machine_ctrl.ros import messages as ros_io
    shutil.copy(fts_lathe.urdf_path, tmp_path)
    text = fts_lathe.yaml_path.read_text()
    assert text.count('acceleration_gain: 0.0 ') == 1
    (tmp_path / 'fts_ka4.yaml').write_text(text.replace('acceleration_gain: 0.0 ', 'acceleration_gain: 4.0 '))
    machine = load_machine(tmp_path / 'fts_ka4.yaml')
    held = run(machine, Reference.hold(machine.axis_names, machine.control_period, machine.home, 1), steps=STEPS)
    without = run(fts_lathe, Reference.hold(machine.axis_names, machine.control_period, machine.home, 1), steps=STEPS)
    w = machine.axis_names.index('w')
    assert not np.array_equal(held.effort[:, w], without.effort[:, w])     # the loop acts on W's command

    rogue = ros_node('rogue')
    publisher = rogue.create_publisher(Imu, contract.ACCELEROMETERS.name, ros_io.STEP_QOS)
    seen = {}
    rogue.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, lambda msg: seen.update(
        {st.name: {kv.key: kv.value for kv in st.values} for st in msg.status}), 100)
    executor = SingleThreadedExecutor(context=rogue.context)
    executor.add_node(rogue)

    def reading(stamp, frame='fts', value=1.0):
        msg = ros_io.accelerometer_message(stamp, machine.axis('w'), value)
        msg.header.frame_id = frame
        return msg
    cases = [(reading(Time(sec=0, nanosec=5010), frame='x_slide'), "frame_id 'x_slide' is not the link of w (fts)"),
             (reading(Time(sec=0, nanosec=5010), value=float('nan')), 'linear_acceleration holds NaN or inf'),
             (reading(Time(sec=0, nanosec=1234)), 'stamp 1234 ns is not on the 5010 ns control grid')]

    def inject():
        for count, (msg, reason) in enumerate(cases, start=1):
            while not publisher.get_subscription_count():
                executor.spin_once(timeout_sec=0.05)
            publisher.publish(msg)
            deadline = time.monotonic() + 60
            while not (int(seen.get('servo_fine', {}).get('rejected_messages', 0)) == count
                       and seen['servo_fine']['last_rejection'].endswith(reason)):
                assert time.monotonic() < deadline, (reason, seen.get('servo_fine'))
                ros_supervisor.check()
                executor.spin_once(timeout_sec=0.05)
    try:
        graph = record_graph(machine, ros_node, ros_supervisor, single_process=False, contour='hold', during=inject)
    finally:
        executor.shutdown()
    assert all(np.array_equal(a, b) for a, b in zip(graph, (held.measured, held.measured_velocity, held.effort)))
    assert np.ptp(graph[0][:, w]) > 1e-9 and np.ptp(graph[2][:, w]) > 0      # the noise moved W, the PID answered


def test_dual_stage_switches_off_and_on_at_runtime(micromill, ros_node, ros_supervisor):
    """/dual_stage/enable (std_srvs/SetBool) on the running graph: offsets drop to exactly
    zero while off and come back when on. The offsets are read by step, every step from 0
    (a gap fails the wait): hw_sim holds for this reader's progress (ProgressReporter), so
    no reader queue overflows and no row is missed unseen."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    from std_srvs.srv import SetBool

    from machine_ctrl.ros import messages as ros_io
    node = ros_node('switcher')
    clock = ros_io.StepClock.of(micromill)
    progress = ProgressReporter(node, clock)
    offsets = {}                  # step -> offsets; hw_sim's re-sends of a held step come again

    def on_offsets(msg):
        offsets[clock.step(msg.header.stamp)] = list(msg.position)
        progress.report(held() - 1)

    def held():
        """The first step not held: every step before it is."""
        step = progress.reported + 1
        while step in offsets:
            step += 1
        return step

    # deep: re-sends of a held step add to what waits while the test is busy elsewhere
    node.create_subscription(JointState, contract.DUAL_STAGE_OFFSETS.name, on_offsets,
                             QoSProfile(depth=1_000_000, reliability=ReliabilityPolicy.RELIABLE))
    client = node.create_client(SetBool, '/dual_stage/enable')
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    # hw_sim holds step 0 until this reader reports, then runs at most the window ahead of it
    ros_supervisor.start('graph', [sys.executable, '-m', 'machine_ctrl.ros.graph', '--machine', str(micromill.yaml_path),
                                   '--hw-sim', f'recorder_window={ProgressReporter.WINDOW}',
                                   '--hw-sim', 'wait_for_recorder=true'])

    def spin_until(predicate, timeout=60.0):
        deadline = time.monotonic() + timeout
        while not predicate():
            assert time.monotonic() < deadline, f'timed out; every step held up to {held() - 1}, newest ' \
                                                f'{max(offsets, default=None)}'
            executor.spin_once(timeout_sec=0.05)
            ros_supervisor.check()

    def switch(on):
        """Returns the first steps not held when the switch was asked and when it answered: it
        acts on no step before the first, every row computed after the second sees it."""
        assert client.wait_for_service(timeout_sec=30)
        asked = held()
        future = client.call_async(SetBool.Request(data=on))
        spin_until(future.done)
        assert future.result().success
        return asked, held()

    def zeros_from(since):
        """The step after the last row with a non-zero offset in [since, held()): a row can be
        zero by chance (at rest): the switch acted after the last non-zero row."""
        return max((k + 1 for k in range(since, held()) if any(offsets[k])), default=since)

    try:
        spin_until(lambda: held() > 300)
        assert any(v != 0.0 for k in range(300) for v in offsets[k])          # coupling works
        _, off = switch(False)
        # off: from one step on, every offset is exactly zero (300 steps, then until switched on)
        spin_until(lambda: held() > zeros_from(off) + 300)
        zero = zeros_from(off)
        # it acts on the next row computed: only the rows already under way when it answered
        # come before it (hw_sim runs at most WINDOW + 1 steps ahead of this reader; +2 for the
        # pipeline from the state to the offsets)
        assert zero <= off + ProgressReporter.WINDOW + 3, (off, zero)
        on, _ = switch(True)
        assert all(v == 0.0 for k in range(zero, on) for v in offsets[k]), (zero, on)
        spin_until(lambda: any(v != 0.0 for k in range(on, held()) for v in offsets[k]))     # on again
    finally:
        executor.shutdown()
        ros_supervisor.stop_all()
