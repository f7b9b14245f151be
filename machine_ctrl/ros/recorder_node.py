"""recorder_node: records topics of the graph into a rosbag2/MCAP bag directory
(:mod:`machine_ctrl.recording.recorder` decides what and how; :mod:`machine_ctrl.recording.bag` writes).

Parameters: ``output`` (bag directory, must not exist or be empty), ``topics`` (names, or
``NAME:pkg/msg/Type`` to subscribe before the topic exists; relative names are in the
node's namespace; empty: every topic of the node's namespace but ``/rosout``,
``/parameter_events`` and its own recorder/progress), ``machine`` (name or YAML path, stored in the bag's
custom_data for ``machine-ctrl analyze``), ``discovery_period`` (s, wall), ``duration``
(s, wall; 0: until stopped), ``start_streams`` (bringup's recorder: /joint_states is
subscribed only once that many step nodes have answered, :meth:`RecorderNode.start_states`),
``session`` (KEY=VALUE facts of the recorded graph, kept in custom_data as
machine_ctrl.session.KEY).

Progress: when it records /joint_states, the node publishes on /recorder/progress
(builtin_interfaces/Time, reliable, transient local, depth 1, a 5 s liveliness lease: hw_sim
releases its hold when it lapses) a stamp up to which every
per-step publisher's messages are written (:class:`machine_ctrl.recording.recorder.Progress`; at
start the stamp of step -1, nothing written, when the machine is known), after every ``recorder.PROGRESS_EVERY``-th state and every
``recorder.PROGRESS_PERIOD`` s when newer. hw_sim's ``recorder_window`` uses it to hold the
lock-step graph so no publisher gets further ahead of this node than DDS keeps. Time is the
standard type of a point in ROS time and exactly what is reported (a stamp of the graph's
headers): no header or frame around it that would mean nothing, and not rosgraph_msgs/Clock,
which would read as a clock source.

Stopping (SIGINT, SIGTERM, ``duration``): discovery stops, messages already received by
DDS are drained (until none arrives for ``DRAIN_QUIET`` s), the bag is closed (summary,
footer, metadata.yaml) and the per-topic counts are printed on stdout; then the ROS teardown,
bounded as every node's (node_common.bounded_teardown: a hang prints its stacks, exit 1).

Crash safety: every chunk of the bag reaches the file when it is complete, and a chunk is
completed after at most ``bag.CHUNK_PERIOD`` s (a wall timer every ``FLUSH_CHECK`` s checks,
so a quiet recording is not held back) or ``bag.CHUNK_SIZE`` bytes; completed chunks are
fsynced within ``bag.SYNC_PERIOD`` s. So a recorder killed outright (SIGKILL, OOM killer)
loses at most the last ``CHUNK_PERIOD + FLUSH_CHECK`` s (1.1 s) or 1 MiB of messages, and
``machine-ctrl record --recover DIR`` makes the rest readable.

A write that fails (disk full, a file size limit, an I/O error, a file system remounted
read-only) stops the recording at once, and the node stays up: it logs the error, the bag
keeps its complete chunks (it needs ``--recover``), its subscriptions end, and its
/recorder/progress publisher goes away — hw_sim sees no recorder any more and stops
holding the graph for it (hw_sim's ``recorder_connected``: the progress topic has no
publisher). From then on the node publishes on /diagnostics every second (level ERROR,
name = the node's, message ``recording stopped: <reason>``; nothing while it records, so a
recorder never records its own status), and at its stop it prints the counts of what the
bag holds with the reason, and exits 1. A bag that cannot be created at start (unwritable
or not empty) ends the node at once (exit 2, one line).
"""
from __future__ import annotations

import signal
import sys
import time

import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from machine_ctrl import contract, parameters
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.ros.messages import message_class
from machine_ctrl.recording import recorder
from machine_ctrl.recording.bag import BagError, qos_profile
from machine_ctrl.model.config import load_machine
from machine_ctrl.model.errors import ConfigError
from machine_ctrl.recording.msgdefs import DefinitionNotFound
from machine_ctrl.ros.node_common import (DefaultExecutor, end_process, qos, report_stacks_on_signal, teardown,
                                          wall_timer)
from machine_ctrl.ros.node_parameters import declare_parameters

DRAIN_QUIET = 0.5      # s without a message that ends the drain at stop
DRAIN_LIMIT = 30.0     # s: the drain never takes longer
FLUSH_CHECK = 0.1      # s (wall) between checks whether the open chunk is due (bag.CHUNK_PERIOD)
STATUS_PERIOD = 1.0    # s (wall) between /diagnostics once the recording has stopped
# the latest progress only matters; transient local so that an hw_sim that starts later
# learns at once that a recorder is there and how far it is
PROGRESS_QOS = qos(contract.PROGRESS_QOS)    # with its liveliness lease: hw_sim learns a stop


def offered_profile(qos) -> dict:
    """An rclpy QoSProfile as the bag's profile mapping."""
    def duration(d):
        ns = d.nanoseconds
        sec, nsec = contract.split_ns(ns)
        return {'sec': sec, 'nsec': nsec}
    return qos_profile(reliability=qos.reliability.name.lower(), durability=qos.durability.name.lower(),
                       history=qos.history.name.lower(), depth=qos.depth, deadline=duration(qos.deadline),
                       lifespan=duration(qos.lifespan), liveliness=qos.liveliness.name.lower(),
                       liveliness_lease_duration=duration(qos.liveliness_lease_duration),
                       avoid_ros_namespace_conventions=qos.avoid_ros_namespace_conventions)


class RecorderNode(Node):
    def __init__(self, name: str = 'recorder', **kwargs):
        super().__init__(name, **kwargs)
        values = declare_parameters(self, parameters.RECORDER)
        output, topics, machine = values.output, values.topics, values.machine
        self.discovery_period, self.duration = values.discovery_period, values.duration
        try:
            namespace = self.get_namespace()
            self.wanted = recorder.wanted_topics([t for t in topics if t], namespace) or None
            config = load_machine(machine) if machine else None
            self.recording = recorder.Recording(output, {**self._machine_data(config),
                                                         **recorder.session_data(f for f in values.session if f)},
                                                contract.StepClock.of(config).period_ns if config else None,
                                                namespace)
        except (ValueError, ConfigError) as exc:      # BagError is a ValueError
            self.get_logger().fatal(str(exc))
            raise SystemExit(2) from None
        self.output = output
        self.subscribed: dict[str, object] = {}
        self.last_message = time.monotonic()
        self.started = time.monotonic()
        self.pub_progress = None
        self.progress_timer = None
        self.pub_diag = None
        self.torn_down = False
        self.excluded = recorder.default_excluded(namespace)
        self.states_topic = contract.JOINT_STATES.full(namespace)
        self.answer_topics = frozenset(topic.full(namespace) for topic in contract.STEP_ANSWERS)
        # /joint_states deferred until this many answer streams have sent (0: not deferred;
        # only while recording every topic: parameters.RECORDER's check)
        self.start_streams = values.start_streams
        if self.wanted is None or self.states_topic in self.wanted:
            self.pub_progress = self.create_publisher(Time, contract.RECORDER_PROGRESS.name, PROGRESS_QOS)
            self.publish_progress()                  # step -1: a recorder is here, nothing written yet
            self.progress_timer = wall_timer(self, recorder.PROGRESS_PERIOD, self.publish_progress)
        for topic, type_name in (self.wanted or {}).items():
            if type_name is not None:
                self.subscribe(topic, type_name, [])
        if self.pub_progress is not None:
            self.subscribe_step_topics(namespace)
        self.discovery = wall_timer(self, self.discovery_period, self.discover)
        wall_timer(self, FLUSH_CHECK, self.check_bag)
        self.discover()
        self.get_logger().info(f'recording to {output}')

    @staticmethod
    def _machine_data(config) -> dict:
        if config is None:
            return {}
        return {recorder.MACHINE_KEY: config.name, recorder.MACHINE_FILE_KEY: str(config.yaml_path)}

    def publish_progress(self) -> None:
        if self.recording.stopped is not None:
            return
        stamp = self.recording.progress.take(time.monotonic())
        if stamp is not None:
            sec, nanosec = contract.split_ns(stamp)
            self.pub_progress.publish(Time(sec=sec, nanosec=nanosec))

    @property
    def stopped(self) -> str | None:
        """Why the recording stopped before the node did (None while it records)."""
        return self.recording.stopped

    def check_bag(self) -> None:
        """Timer: complete an old open chunk; once the recording has stopped, leave the graph
        (subscriptions, progress) and report on /diagnostics."""
        if self.recording.stopped is None:
            try:
                self.recording.flush_if_due()
            except BagError as exc:
                self.stop_recording(str(exc))
        if self.recording.stopped is not None:
            self.tear_down()

    def stop_recording(self, reason: str) -> None:
        """A write failed: say so at once; :meth:`tear_down` follows on the next timer (an
        entity is not destroyed from within its own callback)."""
        self.recording.stop(reason)
        self.get_logger().error(f'recording stopped: {reason}; the node stays up, hw_sim no longer waits for it; '
                                f'recover the bag with: machine-ctrl record --recover {self.output}')

    def tear_down(self) -> None:
        if not self.torn_down:
            self.torn_down = True
            self.discovery.cancel()
            for subscription in self.subscribed.values():
                if subscription is not None:
                    self.destroy_subscription(subscription)
            self.subscribed = dict.fromkeys(self.subscribed)
            if self.pub_progress is not None:       # hw_sim stops holding for this recorder
                self.progress_timer.cancel()
                self.destroy_publisher(self.pub_progress)
                self.pub_progress = None
            self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                                  ros_io.qos(contract.DIAGNOSTICS.qos))
            self.status_timer = wall_timer(self, STATUS_PERIOD, self.publish_status)
            self.publish_status()

    def publish_status(self) -> None:
        held = self.recording.writer.durable_counts()
        values = {'output': self.output, 'messages_in_bag': sum(held.values()),
                  'recover': f'machine-ctrl record --recover {self.output}'}
        self.pub_diag.publish(ros_io.diagnostics(self.get_clock().now().to_msg(), self.get_name(),
                                                 DiagnosticStatus.ERROR, f'recording stopped: {self.stopped}',
                                                 values))

    def discover(self) -> None:
        if self.recording.stopped is not None:
            return
        available = {name: list(types) for name, types in self.get_topic_names_and_types()}
        done = {**self.subscribed, self.states_topic: None} if self.start_streams else self.subscribed
        chosen = recorder.to_subscribe(available, self.wanted, self.excluded, done, self.get_namespace())
        for topic, type_name in chosen.items():
            offers = [offered_profile(info.qos_profile) for info in self.get_publishers_info_by_topic(topic)]
            if offers:                        # wait for a publisher: its QoS decides ours
                self.subscribe(topic, type_name, offers)

    def subscribe_step_topics(self, namespace: str) -> None:
        """The graph's per-step topics (contract.PER_STEP_TOPICS, all reliable and volatile)
        are subscribed at once, not on discovery: hw_sim's `min_subscribers` holds step 0
        only until this node's /joint_states reader is matched, and a per-step topic found a
        discovery round later would lose its first steps (seen: /servo_commands of steps
        0-398 with every node in one process). Such a topic joins the bag with its first
        message (the QoS its publishers offer then), so a topic nobody publishes is not in it.
        With `start_streams`, /joint_states waits for :meth:`start_states`."""
        for topic in contract.PER_STEP_TOPICS:
            name = topic.full(namespace)
            if (self.wanted is None and name not in self.excluded or name in (self.wanted or {})) \
                    and self.subscribed.get(name) is None and not (name == self.states_topic and self.start_streams):
                self.subscribe(name, topic.type, None)

    def start_states(self) -> None:
        """Subscribe /joint_states once `start_streams` answer streams have sent. A DDS writer
        sends a volatile reader only what it publishes after it has matched that reader, and
        each pair of nodes matches in its own time: a step node could answer steps before it
        matched this node and those answers would be lost (seen on a loaded machine:
        /servo_commands of the first steps missing from a bag). A message received proves
        the match; hw_sim, which holds step 0 until this node's /joint_states reader is
        there (min_subscribers), re-sends state 0 meanwhile and the nodes answer it again.
        This node's earlier readers of hw_sim's own topics are matched by then, since the
        readers of one participant are announced to another in the order they were made."""
        if self.recording.progress.streams_on(self.answer_topics) < self.start_streams:
            return
        self.get_logger().info(f'{self.start_streams} answer streams have sent: subscribing {self.states_topic}')
        self.start_streams = 0
        self.subscribe(self.states_topic, contract.JOINT_STATES.type, None)

    def subscribe(self, topic: str, type_name: str, offers: list[dict] | None) -> None:
        """Subscribe `topic`; `offers` None: the bag learns the topic (with its publishers'
        offered QoS) from its first message."""
        try:
            cls = message_class(type_name)
            if offers is not None:
                self.recording.add_topic(topic, type_name, offers)
        except (LookupError, DefinitionNotFound, ValueError) as exc:
            self.get_logger().error(f'not recording {topic}: {exc}', once=True)
            self.subscribed[topic] = None
            return
        want = recorder.subscription_qos(offers) if offers else {
            'reliability': 'reliable', 'durability': 'volatile', 'depth': recorder.QUEUE_DEPTH}
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=want['depth'],
                         reliability=ReliabilityPolicy[want['reliability'].upper()],
                         durability=DurabilityPolicy[want['durability'].upper()])
        unregistered = [offers is None]

        def on_message(data: bytes, topic=topic) -> None:
            if self.recording.stopped is not None:
                return
            now = self.last_message = time.monotonic()
            try:
                if unregistered[0]:
                    unregistered[0] = False
                    self.recording.add_topic(topic, type_name, [offered_profile(info.qos_profile)
                                                                for info in self.get_publishers_info_by_topic(topic)])
                due = self.recording.write(topic, data, time.time_ns(), now)
            except BagError as exc:
                self.stop_recording(str(exc))
                return
            if due and self.pub_progress is not None:
                self.publish_progress()
            if self.start_streams and topic in self.answer_topics:
                self.start_states()

        self.subscribed[topic] = self.create_subscription(cls, topic, on_message, qos, raw=True)
        self.get_logger().info(f'subscribed {topic} ({type_name})')

    def finish(self) -> str:
        """Close the bag; the report text."""
        try:
            self.recording.close()
        except BagError as exc:
            self.get_logger().error(f'recording stopped: {exc}')
        return self.recording.report()


def run(node: RecorderNode) -> int:
    """Spin until SIGINT/SIGTERM or the node's duration, drain, close, report, and end the
    process (node_common.end_process: this does not return) with exit status 0, or 1 if the
    recording stopped early (a write failed)."""
    executor = DefaultExecutor()
    executor.add_node(node)
    stop = Future()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.done() or stop.set_result(True))
    try:
        while not stop.done() and rclpy.ok():
            executor.spin_until_future_complete(stop, timeout_sec=0.1)
            if node.duration and time.monotonic() - node.started >= node.duration:
                break
        node.discovery.cancel()
        drain_start = time.monotonic()
        while rclpy.ok() and node.stopped is None and time.monotonic() - node.last_message < DRAIN_QUIET \
                and time.monotonic() - drain_start < DRAIN_LIMIT:
            executor.spin_until_future_complete(Future(), timeout_sec=0.05)
    finally:
        print(node.finish(), flush=True)
        teardown(executor, [node])    # the bag is closed: nothing is lost if this hangs
    end_process(0 if node.stopped is None else 1)


def main(args=None) -> int:
    report_stacks_on_signal()
    rclpy.init(args=sys.argv if args is None else args, signal_handler_options=SignalHandlerOptions.NO)
    try:
        try:
            node = RecorderNode()
        except SystemExit as exc:
            return int(exc.code or 1)
        return run(node)
    finally:
        rclpy.try_shutdown()


if __name__ == '__main__':
    raise SystemExit(main())
