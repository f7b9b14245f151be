"""replay_node: republishes a bag (:mod:`machine_ctrl.recording.replay` decides what and when).

Parameters: ``bag`` (directory or .mcap), ``rate`` (factor on the recorded timing, > 0),
``topics`` (empty: all), ``start_offset`` (s into the bag), ``loop``, ``wait_for_subscribers``
(start only once every publisher has this many matched subscriptions, e.g. a recorder),
``wait_timeout`` (s for that). Publishers offer the recorded QoS (reliability, durability)
and keep a whole pass (KEEP_LAST, depth = the pass's message count): a reliable subscriber
that falls behind (its process starved of CPU, or stopped) gets every message later, where
a shorter queue dropped the oldest unacknowledged ones (a loaded CI run: a recorder fed at
rate 2 lost 3 of 20001 states with depth 1000). The depth is a bound, not allocated up
front, and the queue holds at most one pass, which this node holds in memory anyway. At the
end it waits until every subscriber has acknowledged everything (up to ACK_WAIT s, or a
pass's duration if longer), prints the counts and exits; 1 when some subscriber did not
(it may have lost messages). The playing sleeps between messages in the main thread; the
node's services (its parameters: `ros2 param`) are answered meanwhile by an executor in a
thread of its own.
"""
from __future__ import annotations

import sys
import threading
import time

import rclpy
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from machine_ctrl import contract
from machine_ctrl.recording import replay
from machine_ctrl.recording.bag import Bag
from machine_ctrl.recording.recorder import namespace_of
from machine_ctrl import parameters
from machine_ctrl.ros.node_common import report_stacks_on_signal
from machine_ctrl.ros.node_parameters import declare_parameters
from machine_ctrl.ros.messages import message_class

# s, assumed: how long every subscriber has, after the last message, to acknowledge everything
# (a bound: the wait ends at the last acknowledgement). A recorder continued after a stop
# needed more than 10 s for its backlog on a loaded 2-core run (run49).
ACK_WAIT = 30.0


def publisher_qos(offers: list[dict], pass_length: int) -> QoSProfile:
    """The first recorded offer's reliability/durability (reliable, volatile if none), a
    queue for `pass_length` messages (no fewer than offered)."""
    offer = offers[0] if offers else {}
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(int(offer.get('depth', 0) or 0), pass_length, 1),
                      reliability=ReliabilityPolicy[str(offer.get('reliability', 'reliable')).upper()],
                      durability=DurabilityPolicy[str(offer.get('durability', 'volatile')).upper()])


def recorded_offers(bag: Bag) -> dict[str, list]:
    """Topic -> offered QoS profiles from the bag information (empty when unknown)."""
    result = {}
    for entry in bag.information.get('topics_with_message_count') or []:
        meta = entry.get('topic_metadata') or {}
        offers = meta.get('offered_qos_profiles')
        result[meta.get('name')] = offers if isinstance(offers, list) else []
    return result


class ReplayNode(Node):
    def __init__(self, name: str = 'replay', **kwargs):
        super().__init__(name, **kwargs)
        values = declare_parameters(self, parameters.REPLAY)
        path, self.rate, start_offset, self.loop = values.bag, values.rate, values.start_offset, values.loop
        topics = [t for t in values.topics if t]
        self.wait_for, self.wait_timeout = values.wait_for_subscribers, values.wait_timeout
        try:
            with Bag(path) as bag:
                self.messages = replay.select(bag, topics or None, start_offset)
                offers = recorded_offers(bag)
                types = {name: info.type for name, info in bag.topics.items()}
                self.clock_topic = contract.CLOCK.full(namespace_of(bag.custom_data))
        except (ValueError, LookupError) as exc:          # BagError is a ValueError
            self.get_logger().fatal(str(exc))
            raise SystemExit(2) from None
        self.clock = replay.ClockSource(self.messages, self.clock_topic)
        self.pass_seconds = contract.ns_to_seconds(self.messages[-1].log_time - self.messages[0].log_time) / self.rate
        self.publishers_by_topic = {}
        for topic in sorted({m.topic for m in self.messages} | {self.clock_topic}):
            type_name = types.get(topic, contract.CLOCK.type)
            try:
                cls = message_class(type_name)
            except LookupError as exc:
                self.get_logger().fatal(f'{topic}: {exc}')
                raise SystemExit(2) from None
            self.publishers_by_topic[topic] = self.create_publisher(cls, topic, publisher_qos(offers.get(topic, []), len(self.messages)))
        self.counts = dict.fromkeys(self.publishers_by_topic, 0)

    def wait_for_subscribers(self) -> bool:
        deadline = time.monotonic() + self.wait_timeout
        while rclpy.ok() and time.monotonic() < deadline:
            if all(p.get_subscription_count() >= self.wait_for for p in self.publishers_by_topic.values()):
                return True
            time.sleep(0.05)
        return False

    def publish(self, topic: str, data: bytes) -> None:
        self.publishers_by_topic[topic].publish(data)
        self.counts[topic] += 1

    def play_pass(self) -> bool:
        """One pass through the messages on schedule; False if interrupted."""
        first = self.messages[0].log_time
        started = time.monotonic()
        for message in self.messages:
            due = contract.ns_to_seconds(message.log_time - first) / self.rate
            while (ahead := due - (time.monotonic() - started)) > 0:
                if not rclpy.ok():
                    return False
                time.sleep(min(ahead, 0.05))
            stamp = self.clock.stamp_for(message)
            if stamp is not None:
                self.publish(self.clock_topic, replay.clock_bytes(stamp))
            if message.topic != self.clock_topic:
                self.publish(message.topic, message.data)
        return rclpy.ok()

    def run(self) -> int:
        """Wait for the subscribers, play, wait for their acknowledgements; the exit status.
        The services are answered meanwhile (module docstring)."""
        executor = SingleThreadedExecutor(context=self.context)
        executor.add_node(self)
        services = threading.Thread(target=executor.spin, name='replay services', daemon=True)
        services.start()
        try:
            return self.play()
        finally:
            executor.shutdown()
            services.join()

    def play(self) -> int:
        if self.wait_for > 0 and not self.wait_for_subscribers():
            self.get_logger().fatal(f'fewer than {self.wait_for} subscribers on some topic after '
                                    f'{self.wait_timeout:g} s')
            return 1
        number = 0
        while self.play_pass() and self.loop:
            number += 1
            self.clock.new_pass(number)
        wait = max(ACK_WAIT, self.pass_seconds)        # a subscriber's backlog may be a whole pass
        deadline = time.monotonic() + wait             # one bound for every topic together
        unacknowledged = [topic for topic, publisher in self.publishers_by_topic.items()
                          if not publisher.wait_for_all_acked(
                              Duration(seconds=max(deadline - time.monotonic(), 0.0)))]
        print(f'replayed {sum(self.counts.values())} messages', flush=True)
        for topic, count in sorted(self.counts.items()):
            print(f'  {topic}: {count}', flush=True)
        if unacknowledged:
            self.get_logger().error(f'not every subscriber acknowledged everything within {wait:g} s on '
                                    f'{", ".join(unacknowledged)}: they may have lost messages')
            return 1
        return 0


def main(args=None, overrides=()) -> int:
    """`replay_node` (ROS arguments from argv) and `machine-ctrl replay` (parameter overrides)."""
    report_stacks_on_signal()
    rclpy.init(args=sys.argv if args is None else args)
    try:
        try:
            node = ReplayNode(parameter_overrides=list(overrides))
        except SystemExit as exc:
            return int(exc.code or 1)
        try:
            return node.run()
        finally:
            node.destroy_node()
    except KeyboardInterrupt:
        return 130
    finally:
        rclpy.try_shutdown()


if __name__ == '__main__':
    raise SystemExit(main())
