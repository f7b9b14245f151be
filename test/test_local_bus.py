"""The per-step streams between nodes of one process (machine_ctrl.ros.local_bus), over real
DDS and the nodes' executor: each message reaches each reader once and in order, whether it
came through the bus, through DDS from another participant, or both ways (someone outside
reads too, also joining and leaving mid-stream, with two writers on the topic and a message
sent twice); nothing goes to DDS while nobody outside reads; a reader keeps the last `depth`
like its DDS history; a stream that never pauses leaves the executor to others; a reader
outside the control loop comes after its answers, yet keeps up with a loop that never
pauses; a callback that raises is logged on its node. test_graph checks that a
single-process graph runs it."""
import functools
import time

import pytest

from ros_fixtures import private_context

TOPIC = '/local_bus_test'
GUARD = 60.0          # s: a failure guard only (2 busy cores)


class Nodes:
    """Nodes of this process on one executor of the kind the nodes spin on
    (node_common.DefaultExecutor); the bus runs for them after :meth:`start`."""

    def __init__(self, ros_node):
        from machine_ctrl.ros.node_common import DefaultExecutor
        self.ros_node, self.nodes, self.executor = ros_node, [], None
        self.make_executor = DefaultExecutor

    def node(self, name: str):
        node = self.ros_node(name)
        self.nodes.append(node)
        return node

    def writer(self, name: str, topic: str = TOPIC):
        """A StepWriter; its `sent` lists what it sent to DDS."""
        from sensor_msgs.msg import JointState

        from machine_ctrl.ros.local_bus import StepWriter
        writer = StepWriter(self.node(name), JointState, topic, step_qos())
        writer.sent = []
        to_dds = writer.publisher.publish
        writer.publisher.publish = lambda data: (writer.sent.append(data), to_dds(data))
        return writer

    def reader(self, name: str, topic: str = TOPIC, depth: int = 200, take=None, later: bool = False) -> list:
        """What a reader got (`take(got, data)`: its callback, default: keep all; `later`: a
        reader outside the control loop)."""
        from sensor_msgs.msg import JointState

        from machine_ctrl import contract
        from machine_ctrl.ros.local_bus import subscribe_raw
        from machine_ctrl.ros.messages import qos
        got = []
        subscribe_raw(self.node(name), JointState, topic, got.append if take is None else (lambda d: take(got, d)),
                      qos(contract.Qos(depth=depth)), later)
        return got

    def start(self) -> None:
        from machine_ctrl.ros.local_bus import BUS
        self.executor = self.make_executor(context=self.nodes[0].context)
        for node in self.nodes:
            self.executor.add_node(node)
        BUS.start(self.executor, self.nodes)


@pytest.fixture
def local(ros_node):
    from machine_ctrl.ros.local_bus import BUS
    nodes = Nodes(ros_node)
    try:
        yield nodes
    finally:
        BUS.stop()
        if nodes.executor is not None:
            nodes.executor.shutdown()


def step_qos():
    from machine_ctrl import contract
    from machine_ctrl.ros.messages import qos
    return qos(contract.STEP_QOS)


@functools.cache
def message(i: int) -> bytes:
    """Message i, the same bytes each time (serialize_message leaves padding bytes as they were)."""
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState
    msg = JointState(name=['x'], position=[float(i)])
    msg.header.stamp.sec = i
    return serialize_message(msg)


def spin_until(executors, condition, what):
    end = time.monotonic() + GUARD
    while not condition():
        assert time.monotonic() < end, f'{what}: not within {GUARD} s'
        for executor in executors:
            executor.spin_once(timeout_sec=0.01)


def test_readers_in_the_process_get_each_message_once_in_order_and_dds_carries_none(local):
    writer = local.writer('bus_writer')
    got = [local.reader('bus_reader_a'), local.reader('bus_reader_b')]
    local.start()
    sent = [message(i) for i in range(150)]        # fewer than a reader keeps (depth 200)
    for data in sent:
        writer.publish(data)
    spin_until([local.executor], lambda: all(len(g) >= len(sent) for g in got), 'every message at both readers')
    assert got == [sent, sent]
    assert writer.sent == []                        # nobody outside the process reads
    assert writer.get_subscription_count() == 2     # the readers keep their DDS subscriptions


def test_a_reader_outside_joining_and_leaving_gets_its_part_and_none_here_gets_one_twice(ros_env, local):
    """Two writers on the topic; a reader in another participant joins after the first
    messages and leaves before the last; one message is sent twice while it reads."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    from machine_ctrl.ros.local_bus import BUS
    writers = [local.writer('bus_writer_a'), local.writer('bus_writer_b')]
    got = [local.reader('bus_reader_a'), local.reader('bus_reader_b')]
    local.start()
    readers = BUS.readers_of(writers[0].topic)
    sent = []

    def send(first: int, count: int) -> list:
        batch = [message(i) for i in range(first, first + count)]
        for i, data in enumerate(batch):
            writers[i % 2].publish(data)
        sent.extend(batch)
        return batch

    send(0, 50)
    with private_context(ros_env) as other:
        outside_node = Node('bus_outside_reader', context=other)
        outside = SingleThreadedExecutor(context=other)
        outside.add_node(outside_node)
        heard = []
        subscription = outside_node.create_subscription(JointState, TOPIC, heard.append, step_qos(), raw=True)
        try:
            spin_until([local.executor, outside], lambda: all(w.get_subscription_count() == 3 for w in writers),
                       'the outside reader matched')
            middle = send(50, 100)
            writers[1].publish(middle[-1])          # the last one again (as hw_sim re-sends a state)
            sent.append(middle[-1])
            middle.append(middle[-1])
            spin_until([local.executor, outside], lambda: len(heard) >= len(middle), 'the outside reader got them')
        finally:
            outside_node.destroy_subscription(subscription)
            outside.shutdown()
            outside_node.destroy_node()
    spin_until([local.executor], lambda: all(w.get_subscription_count() == 2 for w in writers), 'the outside reader gone')
    send(151, 50)
    # done when every message is here and every DDS copy of one has come and been dropped
    spin_until([local.executor], lambda: all(len(g) >= len(sent) for g in got) and not any(r.echoes for r in readers),
               'every message here, every copy dropped')
    assert got == [sent, sent]
    by_writer = [middle[0:100:2], middle[1:100:2] + middle[100:]]
    for writer, its in zip(writers, by_writer):
        assert writer.sent == its                   # to DDS: what it sent while the reader outside read
        assert [data for data in heard if data in its] == its     # DDS keeps each writer's order only
    assert len(heard) == len(middle)


def test_a_writer_outside_reaches_the_readers_through_dds(ros_env, local):
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    local.writer('bus_writer')                      # a writer here too: the bus runs for the topic
    got = [local.reader('bus_reader_a'), local.reader('bus_reader_b')]
    local.start()
    with private_context(ros_env) as other:
        outside = Node('bus_outside_writer', context=other)
        try:
            publisher = outside.create_publisher(JointState, TOPIC, step_qos())
            spin_until([local.executor], lambda: publisher.get_subscription_count() == 2, 'the readers matched')
            sent = [message(i) for i in range(50)]
            for data in sent:
                publisher.publish(data)
            spin_until([local.executor], lambda: all(len(g) >= len(sent) for g in got), 'every message at both readers')
            assert got == [sent, sent]
        finally:
            outside.destroy_node()


def test_with_the_bus_stopped_the_readers_get_the_messages_through_dds(local):
    from machine_ctrl.ros.local_bus import BUS
    writer = local.writer('bus_writer')
    got = local.reader('bus_reader')
    local.start()
    BUS.stop()
    spin_until([local.executor], lambda: writer.get_subscription_count() == 1, 'the reader matched')
    sent = [message(i) for i in range(20)]
    for data in sent:
        writer.publish(data)
    spin_until([local.executor], lambda: len(got) >= len(sent), 'every message')
    assert got == sent
    assert writer.sent == sent


def test_a_reader_keeps_the_last_depth_messages_like_its_history(local):
    writer = local.writer('bus_writer')
    got = local.reader('bus_reader', depth=5)
    local.start()
    sent = [message(i) for i in range(20)]
    for data in sent:                   # all queued before the executor delivers any (one task)
        writer.publish(data)
    spin_until([local.executor], lambda: len(got) >= 5, 'the newest five')
    assert got == sent[-5:]


def test_a_callback_that_fails_is_logged_on_its_node_and_the_next_message_delivered(local, capfd):
    def take(got, data):
        if data == message(1):
            raise ValueError('bad message')
        got.append(data)
    writer = local.writer('bus_writer')
    got = local.reader('bus_failing_reader', take=take)
    local.start()
    for i in range(3):
        writer.publish(message(i))
    spin_until([local.executor], lambda: len(got) >= 2, 'the messages after the failing one')
    assert got == [message(0), message(2)]
    log = capfd.readouterr().err
    assert '[bus_failing_reader]: callback failed: Traceback' in log and 'ValueError: bad message' in log, log


def test_a_stream_that_never_pauses_leaves_the_executor_to_timers(local):
    """Two nodes answering each other through the bus, ROUNDS messages in all with no pause:
    a timer of a third node runs while they are still being exchanged (each executor task
    delivers for at most local_bus.SLICE; one task for the whole exchange would let the timer
    run only after it). The exchange ends by count, not by the clock."""
    from rclpy.clock import Clock, ClockType
    rounds = 20_000          # ~0.1 s or more of callbacks: many 10 ms timer periods
    exchanged = []
    there, back = local.writer('bus_ping', TOPIC), local.writer('bus_pong', TOPIC + '_back')

    def answer(target):
        def take(_got, data):
            exchanged.append(1)
            if len(exchanged) < rounds:
                target.publish(data)
        return take
    local.reader('bus_ping_reader', TOPIC + '_back', take=answer(there))
    local.reader('bus_pong_reader', TOPIC, take=answer(back))
    ticks = []
    local.node('bus_timer').create_timer(0.01, lambda: ticks.append(len(exchanged)),
                                         clock=Clock(clock_type=ClockType.STEADY_TIME))
    local.start()
    there.publish(message(0))
    spin_until([local.executor], lambda: len(exchanged) >= rounds and ticks, 'the exchange done and a timer tick')
    assert ticks[0] < rounds, 'the timer ran only once the exchange had stopped'
    assert any(0 < n < rounds for n in ticks), ticks[:5]


def test_a_reader_outside_the_loop_comes_after_the_loops_answer(local, monkeypatch):
    """A state to a loop reader and to a reader outside the loop (contour_error's kind); the
    loop reader answers on another topic: the answer is delivered before the state reaches
    the reader outside, though the state was posted first. (One task delivers it all: the
    slice is made longer than a descheduled thread could make it end early.)"""
    from machine_ctrl.ros import local_bus
    monkeypatch.setattr(local_bus, 'SLICE', GUARD)
    order = []
    answers = local.writer('bus_servo', TOPIC + '_back')

    def servo(_got, data):
        order.append(('servo', data))
        answers.publish(data)
    writer = local.writer('bus_hw_sim')
    local.reader('bus_servo_reader', take=servo)
    local.reader('bus_contour_reader', take=lambda _got, data: order.append(('contour', data)), later=True)
    local.reader('bus_hw_sim_reader', TOPIC + '_back', take=lambda _got, data: order.append(('hw_sim', data)))
    local.start()
    writer.publish(message(0))
    spin_until([local.executor], lambda: len(order) >= 3, 'the state and its answer delivered')
    assert order == [('servo', message(0)), ('hw_sim', message(0)), ('contour', message(0))]


def test_a_reader_outside_the_loop_keeps_up_with_a_loop_that_never_pauses(local):
    """A lock-step loop through the bus (two nodes answering each other at once, each round a
    new message) and a reader outside it on one of the loop's topics: that reader is served
    while the loop runs (each task ends with what waits for it) and gets every message, in
    order. Its depth is larger than the messages of one task here (a trivial loop makes far
    more than the graph's ~10 steps per task): this checks the order of service, not the
    depth."""
    rounds = 3000
    sent, served_while = [], []
    there, back = local.writer('bus_ping', TOPIC), local.writer('bus_pong', TOPIC + '_back')

    def ping(_got, _data):
        if len(sent) < rounds:
            sent.append(message(len(sent)))
            there.publish(sent[-1])

    def outside(got, data):
        got.append(data)
        served_while.append(len(sent) < rounds)
    local.reader('bus_ping_reader', TOPIC + '_back', take=ping)                      # sends on TOPIC
    local.reader('bus_pong_reader', TOPIC, take=lambda _got, data: back.publish(data))
    got = local.reader('bus_outside_loop_reader', depth=100_000, take=outside, later=True)
    local.start()
    sent.append(message(0))
    there.publish(sent[-1])
    spin_until([local.executor], lambda: len(got) >= rounds, 'every message at the reader outside the loop')
    assert got == sent
    assert served_while[0], 'the reader outside the loop was served only once the loop had stopped'
