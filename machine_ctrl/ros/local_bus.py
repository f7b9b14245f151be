"""In-process delivery of the per-step streams (/joint_states, /servo_commands, the dual-stage
offsets) between nodes of one process: a single-process graph (`bringup --single-process`,
python -m machine_ctrl.ros.graph). Like rclcpp's intra-process communication, which rclpy
does not have.

Without it a message between two nodes of the same process still goes through Fast DDS
(the writer's history, an intra-process delivery, the reader's history, an executor event
and a take): ~40 % of a single-process graph's time, publishing 15 %, the executor's takes
and dispatch 25 % (bench/RESULTS.md "[5/8] One process: the per-step streams without
DDS"). With it:

* A writer (:class:`StepWriter`) hands the CDR bytes it publishes anyway to the readers of
  its topic in this process, through a queue that the executor drains: run to completion,
  one executor task at a time, each task at most :data:`SLICE` s long, so that timers,
  services and messages from other processes still get their turn (never from inside the
  publishing callback: a node never runs inside another node's publish).
* It publishes to DDS only while someone outside the process reads the topic (a recorder,
  a client, `ros2 topic echo`): more matched subscriptions than this process's readers.
* Every reader (:class:`LocalReader`) keeps its DDS subscription: `ros2 node info`,
  `ros2 topic info` and the matched counts are as before, and messages from other processes
  (a hw_sim elsewhere, a user's `ros2 topic pub`) arrive through it as before. A message of
  a local writer that also went to DDS (someone outside reads) reaches such a reader twice;
  the reader takes it from the queue and drops the DDS copy: one equal to a payload the
  writer marked as also sent. A reader keeps as many such marks as its DDS history keeps
  messages (the QoS depth): more copies cannot be waiting for it. A mark whose copy never
  comes (DDS dropped it, or the reader was not matched yet) stays until as many newer ones
  push it out; meanwhile an equal payload from another process would be taken for the copy.
* What waits for a reader is bounded like its DDS history: keep last `depth` (the topic's
  QoS); the oldest is dropped, as DDS would.
* A task delivers for up to :data:`SLICE` (then what waits for readers outside the control
  loop, below); a paced hw_sim's timer (or anything else the executor has) may wait that
  long behind it, where it waited one message before.
* The control loop first: a reader that is not part of it (``later=True``: contour_error's
  states) gets its messages once no loop reader has one waiting, and at the end of each
  task whatever is waiting for it, so that it keeps up with a lock-step loop that never
  pauses (at most a task's worth behind, far less than its depth). Without that, a step's
  commands waited behind the estimation of the state they answer (paced trt_5axis at 1 kHz:
  step latency p50 ~0.2 ms, 0.11 ms without; bench/RESULTS.md). Each reader still gets its
  messages in order; only the interleaving of readers within a task changes: the loop's
  messages are as before (test_graph, test_determinism), and contour_error gets each state
  within the task that posted it (before, entries left at a task's end waited for the next).

Only while the bus runs (:meth:`LocalBus.start`, by node_common.spin for several nodes in
one executor) and only for readers of the nodes it runs for; otherwise every writer
publishes to DDS and every reader takes from it (a process per node).
"""
from __future__ import annotations

import time
import traceback
from collections import deque

from rclpy.node import Node

# assumed: 2 ms of the control loop's callbacks at a time, then the readers outside it for
# what those 2 ms posted (contour_error: its estimation of those states, about as long again
# on the micromill). The 20 ms timers of the step nodes and the 1 s diagnostics then run at
# most a few ms late; a task per ~10 steps of the micromill's graph costs ~10 us (an
# executor task), nothing beside the callbacks.
SLICE = 0.002              # s (wall)


class LocalReader:
    """One reader of a topic in this process: `callback(data)` for each message (CDR bytes),
    whichever way it came; :meth:`from_dds` is its DDS subscription's callback. `logger`:
    its node's, for a callback that raises on a message of the bus."""

    __slots__ = ('callback', 'logger', 'pending', 'echoes', 'later')

    def __init__(self, callback, depth: int, logger, later: bool = False):
        self.callback, self.logger, self.later = callback, logger, later
        self.pending = deque(maxlen=depth)      # messages of local writers not taken yet
        self.echoes = deque(maxlen=depth)       # payloads of local writers also sent to DDS

    def from_dds(self, data: bytes) -> None:
        if self.echoes:
            try:
                self.echoes.remove(data)        # the first equal one: usually the oldest
                return
            except ValueError:
                pass
        self.callback(data)


class LocalBus:
    """The readers of this process by topic (fully qualified name) and the queue between
    writers and readers; one per process (:data:`BUS`), used from the executor's thread only
    (the nodes' EventsExecutor runs every callback in the thread that spins it)."""

    def __init__(self):
        self.readers: dict[str, list[LocalReader]] = {}
        self.executor = None
        # one entry per message posted, in order, for the readers of the control loop and
        # for the others (a reader's message dropped by its keep-last leaves its entry,
        # skipped when drained)
        self.queue: deque[LocalReader] = deque()
        self.later: deque[LocalReader] = deque()
        self.scheduled = False

    def start(self, executor, nodes: list[Node]) -> int:
        """Deliver from now on to the readers of `nodes` (:func:`subscribe_raw`), draining in
        tasks of `executor`, which spins them. Returns the number of readers."""
        self.stop()
        for node in nodes:
            for topic, reader in getattr(node, _READERS, ()):
                self.readers.setdefault(topic, []).append(reader)
        self.executor = executor
        return sum(map(len, self.readers.values()))

    def stop(self) -> None:
        """Deliver no more (what is queued is dropped): writers publish to DDS only."""
        for readers in self.readers.values():
            for reader in readers:
                reader.pending.clear()
                reader.echoes.clear()
        self.readers, self.executor, self.scheduled = {}, None, False
        self.queue.clear()
        self.later.clear()

    def readers_of(self, topic: str):
        """This process's readers of `topic` while the bus runs (else none)."""
        return self.readers.get(topic, ()) if self.executor is not None else ()

    def post(self, readers, data: bytes) -> None:
        """`data` for each of `readers`, delivered by a task of the executor (one is made
        unless one is due already)."""
        queue, later = self.queue, self.later
        for reader in readers:
            reader.pending.append(data)
            (later if reader.later else queue).append(reader)
        if not self.scheduled:
            self.scheduled = True
            self.executor.create_task(self.drain)

    def drain(self) -> None:
        """One slice of deliveries (executor task): the control loop's readers first, the
        others when none of those has a message waiting; at the slice's end the others get
        everything waiting for them (module docstring). The next slice is another task,
        behind whatever else the executor has by then."""
        queue, later = self.queue, self.later
        end = time.monotonic() + SLICE
        try:
            while queue or later:
                self.deliver((queue or later).popleft())
                if time.monotonic() > end:
                    while later:
                        self.deliver(later.popleft())
                    break
        finally:
            if (queue or later) and self.executor is not None:
                self.executor.create_task(self.drain)
            else:
                self.scheduled = False

    @staticmethod
    def deliver(reader: LocalReader) -> None:
        """The reader's oldest waiting message, if its keep-last left one. A callback that
        raises is logged on its node's logger with the traceback (an executor task would keep
        the exception to itself), and the next message is delivered as usual."""
        if reader.pending:
            try:
                reader.callback(reader.pending.popleft())
            except Exception:  # noqa: BLE001 - a node never dies from a callback error
                reader.logger.error(f'callback failed: {traceback.format_exc()}', throttle_duration_sec=1.0)


BUS = LocalBus()


class StepWriter:
    """The publisher of a per-step stream (CDR bytes): to this process's readers through the
    bus, to DDS while someone outside reads (or while the bus does not run)."""

    def __init__(self, node: Node, msg_type, topic: str, qos):
        self.publisher = node.create_publisher(msg_type, topic, qos)
        self.topic = self.publisher.topic_name

    def publish(self, data: bytes) -> None:
        local = BUS.readers_of(self.topic)
        if not local:
            self.publisher.publish(data)
            return
        if self.publisher.get_subscription_count() > len(local):     # a reader outside too
            for reader in local:
                reader.echoes.append(data)
            self.publisher.publish(data)
        BUS.post(local, data)

    def get_subscription_count(self) -> int:
        """Matched subscriptions, this process's readers included (they keep theirs)."""
        return self.publisher.get_subscription_count()


_READERS = '_machine_ctrl_local_readers'     # a node's [(topic, LocalReader)]: they live as long as it


def subscribe_raw(node: Node, msg_type, topic: str, callback, qos, later: bool = False):
    """A raw subscription (the DDS one is returned; `qos` keep last) whose messages from
    writers of this process come through the bus while it runs for `node`:
    `callback(data)` once per message either way. `later`: a reader outside the control
    loop, served after its readers (module docstring)."""
    reader = LocalReader(callback, qos.depth, node.get_logger(), later)
    subscription = node.create_subscription(msg_type, topic, reader.from_dds, qos, raw=True)
    vars(node).setdefault(_READERS, []).append((subscription.topic_name, reader))
    return subscription
