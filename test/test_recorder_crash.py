"""The recorder node when things go wrong, over real DDS (the session's isolated domain):

* killed outright (SIGKILL) mid-recording: `machine-ctrl record --recover` makes the bag
  readable by the indexed reader, mcap's summary reader and rosbags, with at least every
  message that was in a complete chunk before the kill (waited for: the file is read while
  the recorder writes it), a prefix of what was published, and the custom_data it started
  with (machine, namespace; the loss check recomputed);
* its bag cannot be written any more (a file size limit in the recorder's process: EFBIG,
  what a full disk does with ENOSPC): the error is logged at once, the node stays up, its
  subscriptions and its /recorder/progress publisher go away, /diagnostics says "recording
  stopped: ..." (ERROR), it exits 1 at its stop with a report of what the bag holds; and a
  lock-step graph with flow control (hw_sim's recorder_window) that the recorder held runs
  on past the window.

Every wait is on a condition, with a generous deadline that only turns a hang into a
failure."""
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from machine_ctrl.recording import bag as bagmod
from machine_ctrl.recording import recorder
from machine_ctrl.recording.bag import Bag
from ros_fixtures import on_disk

EXE = str(Path(sys.executable).with_name('machine-ctrl'))
PERIOD = 100_000           # ns, the micromill's control period
DEADLINE = 120.0           # s: a hang fails the test after this long, nothing is timed
TOPICS = "['/joint_states:sensor_msgs/msg/JointState', '/clock:rosgraph_msgs/msg/Clock']"


def recorder_argv(bag, machine, file_size_limit=None):
    args = ['--ros-args', '-p', f'output:={bag}', '-p', f'topics:={TOPICS}', '-p', f'machine:={machine}']
    if file_size_limit is None:
        return [sys.executable, '-m', 'machine_ctrl.ros.recorder_node', *args]
    # SIGXFSZ ignored so that a write past the limit fails with EFBIG instead of killing
    wrapper = ('import resource, runpy, signal, sys; signal.signal(signal.SIGXFSZ, signal.SIG_IGN); '
               f'resource.setrlimit(resource.RLIMIT_FSIZE, ({file_size_limit}, {file_size_limit})); '
               "sys.argv = ['recorder_node'] + sys.argv[1:]; "
               "runpy.run_module('machine_ctrl.ros.recorder_node', run_name='__main__')")
    return [sys.executable, '-c', wrapper, *args]


def wait_until(condition, what, spin=None):
    deadline = time.monotonic() + DEADLINE
    while not condition():
        assert time.monotonic() < deadline, f'waited {DEADLINE:g} s for {what}'
        if spin is not None:
            spin()
        else:
            time.sleep(0.05)


class Publisher:
    """/joint_states every step and /clock every 10th, stamped on the micromill's grid, in
    batches."""

    def __init__(self, node):
        from rclpy.qos import QoSProfile
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        self.node, self.step = node, 0
        self.Clock, self.JointState = Clock, JointState
        self.states = node.create_publisher(JointState, '/joint_states', QoSProfile(depth=1000))
        self.clock = node.create_publisher(Clock, '/clock', QoSProfile(depth=1000))

    def matched(self) -> bool:
        return self.states.get_subscription_count() >= 1 and self.clock.get_subscription_count() >= 1

    def batch(self, n=200) -> None:
        for _ in range(n):
            sec, nanosec = divmod(self.step * PERIOD, 10**9)
            msg = self.JointState(name=['x_c', 'y_c', 'z_c'], position=[1e-6 * self.step] * 3, effort=[0.1] * 3)
            msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
            self.states.publish(msg)
            if self.step % 10 == 0:
                clock = self.Clock()
                clock.clock.sec, clock.clock.nanosec = sec, nanosec
                self.clock.publish(clock)
            self.step += 1
        time.sleep(0.002)          # a graph's pace, not a flood: the recorder keeps up


def recover(bag):
    done = subprocess.run([EXE, 'record', '--recover', str(bag)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_a_killed_recorder_leaves_a_bag_that_recover_makes_readable(ros_supervisor, ros_node, tmp_path, micromill):
    from rclpy.serialization import deserialize_message
    from rosbags.highlevel import AnyReader
    from sensor_msgs.msg import JointState
    bag = tmp_path / 'bag'
    ros_supervisor.start('recorder', recorder_argv(bag, micromill.yaml_path))
    ros_supervisor.wait_for_line('recorder', 'recording to', timeout=60)
    publisher = Publisher(ros_node('crash_publisher'))
    wait_until(publisher.matched, 'the recorder to subscribe')
    file = bag / 'bag_0.mcap'
    wait_until(lambda: on_disk(file) >= 3000, 'complete chunks on disk', spin=publisher.batch)
    publisher.batch()
    flushed = on_disk(file)                 # every complete chunk before the kill
    ros_supervisor['recorder'].signal_group(signal.SIGKILL)
    assert ros_supervisor.wait('recorder', timeout=60) == -signal.SIGKILL
    published = publisher.step

    with pytest.raises(bagmod.BagError, match='truncated'):
        Bag(bag)
    report = recover(bag)
    assert 'recovered ' in report and 'lost: ' in report and 'custom_data: from the start record' in report
    with Bag(bag) as recovered:
        states = [deserialize_message(m.data, JointState) for m in recovered.messages(['/joint_states'])]
        total = sum(info.count for info in recovered.topics.values())
        custom_data = recovered.custom_data
    assert total >= flushed
    steps = [(s.header.stamp.sec * 10**9 + s.header.stamp.nanosec) // PERIOD for s in states]
    # in the order sent, each once, none made up (without flow control DDS may drop a
    # sample now and then: the loss check, recomputed by the recovery, counts it)
    assert steps == sorted(set(steps)) and 0 <= steps[0] and steps[-1] < published
    assert custom_data[recorder.MACHINE_KEY] == micromill.name and custom_data[recorder.NAMESPACE_KEY] == ''
    assert custom_data['machine_ctrl.lost/joint_states'] == str(steps[-1] - steps[0] + 1 - len(steps))
    assert 'machine_ctrl.lost/clock' in custom_data
    with AnyReader([bag]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert counts['/joint_states'] == len(steps)
        assert sum(1 for _ in reader.messages()) == total
    print(f'published {published} states, {flushed} messages on disk before the kill, {total} recovered')


def test_a_bag_directory_that_cannot_be_created_ends_the_recorder_at_start(ros_env, tmp_path, micromill):
    """README "Disk full": a bag directory that cannot be created ends the recorder at start
    with one line naming it and the reason, exit 2, and nothing written (here its parent is a
    file: the tests run as root, for whom no directory is unwritable)."""
    blocker = tmp_path / 'a_file'
    blocker.write_text('')
    bag = blocker / 'bag'
    result = subprocess.run(recorder_argv(bag, micromill.yaml_path), env=ros_env, capture_output=True, text=True,
                            timeout=DEADLINE)
    assert result.returncode == 2, result
    said = [line for line in (result.stdout + result.stderr).splitlines() if line.strip()]
    assert len(said) == 1 and said[0].endswith(f'{bag}: cannot create: Not a directory'), said
    assert blocker.read_text() == ''


def _diagnostics(node):
    from diagnostic_msgs.msg import DiagnosticArray
    seen = []
    node.create_subscription(DiagnosticArray, '/diagnostics',
                             lambda msg: seen.extend(s for s in msg.status if s.name == 'recorder'), 50)
    return seen


def _progress_publishers(node) -> int:
    return node.count_publishers('/recorder/progress')


def test_a_bag_that_cannot_be_written_stops_the_recording_not_the_node(ros_supervisor, ros_node, tmp_path,
                                                                     micromill):
    from rclpy.executors import SingleThreadedExecutor
    bag = tmp_path / 'bag'
    ros_supervisor.start('recorder', recorder_argv(bag, micromill.yaml_path, file_size_limit=300_000))
    ros_supervisor.wait_for_line('recorder', 'recording to', timeout=60)
    node = ros_node('full_disk_probe')
    publisher, statuses = Publisher(node), _diagnostics(node)
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    wait_until(lambda: publisher.matched() and _progress_publishers(node) == 1, 'the recorder')

    def publish_and_spin():
        publisher.batch()
        executor.spin_once(timeout_sec=0.01)
    wait_until(lambda: statuses, "the recorder's error on /diagnostics", spin=publish_and_spin)
    ros_supervisor.wait_for_line('recorder', 'recording stopped: ', timeout=10)      # logged at once
    status = statuses[0]
    assert status.level == b'\x02' and status.message.startswith('recording stopped: ')
    assert 'File too large (EFBIG)' in status.message
    values = {kv.key: kv.value for kv in status.values}
    assert values['recover'] == f'machine-ctrl record --recover {bag}'
    # the node stays, its subscriptions and progress publisher go (hw_sim no longer holds for it)
    wait_until(lambda: _progress_publishers(node) == 0 and publisher.states.get_subscription_count() == 0,
               'the recorder to leave the topics', spin=lambda: executor.spin_once(timeout_sec=0.05))
    assert ros_supervisor['recorder'].running()
    assert ('recorder', '/') in node.get_node_names_and_namespaces()
    count = len(statuses)
    wait_until(lambda: len(statuses) > count, 'its status repeated', spin=lambda: executor.spin_once(timeout_sec=0.1))
    executor.remove_node(node)

    ros_supervisor['recorder'].signal_group(signal.SIGINT)
    assert ros_supervisor.wait('recorder', timeout=60) == 1
    output = '\n'.join(ros_supervisor['recorder'].tail(40))
    assert f'recorded {values["messages_in_bag"]} messages on 2 topics in the complete chunks of {bag}' in output
    assert 'recording stopped early: ' in output and 'machine-ctrl record --recover' in output
    recover(bag)
    with Bag(bag) as recovered:
        assert sum(info.count for info in recovered.topics.values()) == int(values['messages_in_bag'])


def run_held_graph(supervisor, micromill, window: int, target: int, at=None):
    """The default graph in this process with hw_sim holding for the recorder
    (`recorder_window`), spun until hw_sim reaches step `target` (`at(hw_sim)` is called
    once the recorder has reported, e.g. to stop it); returns (hw_sim's gate, the progress
    steps seen, hw_sim's final step)."""
    import rclpy
    from rclpy.task import Future

    from machine_ctrl.ros.graph import create_nodes, default_graph
    from machine_ctrl.ros.node_common import DefaultExecutor, wall_timer
    rclpy.init()
    nodes, executor = [], None
    try:
        # hw_sim holds step 0 until the recorder's /joint_states reader has matched (bringup's
        # rule), so its progress comes before the target step: on a loaded run hw_sim once got
        # there before the recorder had been discovered
        from machine_ctrl.app.bringup import held_for_recorder
        nodes = create_nodes(held_for_recorder(default_graph(micromill), window))
        executor = DefaultExecutor()
        for node in nodes:
            executor.add_node(node)
        hw_sim = nodes[0]
        # the EventsExecutor returns from a busy spin only when a future completes: a
        # wall timer of hw_sim's completes it at the target step
        reached, reported = Future(), []

        def watch():
            if hw_sim.session.gate.recorded is not None:      # the recorder's newest progress
                reported.append(hw_sim.session.gate.recorded)
                if at is not None and len(reported) == 1:
                    at(hw_sim)
            if hw_sim.session.step >= target and not reached.done():
                reached.set_result(True)
        timer = wall_timer(hw_sim, 0.05, watch)
        deadline = time.monotonic() + 300
        while not reached.done():
            assert time.monotonic() < deadline, f'hw_sim reached step {hw_sim.session.step} only'
            supervisor.check()
            executor.spin_until_future_complete(reached, timeout_sec=0.2)
        timer.cancel()
        assert hw_sim.sim.fault is None
        print(f'recorder progress seen up to step {max(reported, default=None)}, hw_sim at {hw_sim.session.step}, '
              f'holds {hw_sim.session.gate.hold_count}, recorders lost {hw_sim.session.gate.lost}')
        return hw_sim.session.gate, reported, hw_sim.session.step
    finally:
        if executor is not None:
            executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()


def test_a_graph_held_for_a_recorder_runs_on_when_its_recording_stops(ros_env, tmp_path, micromill):
    """hw_sim with recorder_window holds the lock-step graph for the recorder; the recorder's
    bag hits a file size limit early in the run; hw_sim must not wait for it forever."""
    from machine_ctrl.app.processes import Supervisor
    window, target = 100, 15_000
    bag = tmp_path / 'bag'
    with Supervisor(ros_env, log_dir=tmp_path / 'logs', stop_timeout=10.0) as supervisor:
        supervisor.start('recorder', recorder_argv(bag, micromill.yaml_path, file_size_limit=150_000))
        supervisor.wait_for_line('recorder', 'recording to', timeout=60)
        gate, reported, _ = run_held_graph(supervisor, micromill, window, target)
        # flow control was on (the recorder reported), and hw_sim ran past its window
        assert reported and max(reported) + window < target
        supervisor.wait_for_line('recorder', 'recording stopped: ', timeout=10)
        assert supervisor['recorder'].running()
        supervisor.stop('recorder')
        assert supervisor['recorder'].returncode == 1
    assert gate.recorded is None                          # it left the graph: no more holding
    output = '\n'.join(supervisor['recorder'].tail(40))
    assert 'File too large (EFBIG)' in output


def test_a_stopped_recorder_is_lost_by_its_liveliness_and_hw_sim_runs_on(ros_env, tmp_path, micromill):
    """README "Faults": a recorder that stops (SIGSTOP: hung, not gone from the graph) stops
    asserting its liveliness; hw_sim releases its hold within the lease (5 s) instead of
    waiting for it for ever, counts it as lost, and the graph runs on past its window."""
    from machine_ctrl.app.processes import Supervisor
    window, target = 100, 8_000
    with Supervisor(ros_env, log_dir=tmp_path / 'logs', stop_timeout=10.0) as supervisor:
        supervisor.start('recorder', recorder_argv(tmp_path / 'bag', micromill.yaml_path))
        supervisor.wait_for_line('recorder', 'recording to', timeout=60)
        try:
            gate, reported, step = run_held_graph(
                supervisor, micromill, window, target,
                at=lambda _hw_sim: supervisor['recorder'].signal_group(signal.SIGSTOP))
        finally:
            supervisor['recorder'].signal_group(signal.SIGCONT)
        assert gate.lost >= 1 and max(reported) + window < step
