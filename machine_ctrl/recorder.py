"""Recording core (no rclpy): which topics to record, with which subscription QoS, and the
bag they go to. :mod:`machine_ctrl.recorder_node` wires it to the ROS graph.

* Topics: every topic of the graph except ``/rosout`` and ``/parameter_events`` (ROS's log
  and parameter traffic, noise for analysis; name them to record them), or the named ones.
  A name may carry its type, ``/joint_states:sensor_msgs/msg/JointState``: such a topic is
  subscribed at once, before any publisher exists, so nothing its first publisher sends is
  missed; others are subscribed when discovery first sees a publisher.
* QoS (rosbag2's rule): reliable unless some publisher offers only best effort (a reliable
  reader would not match it), transient local when every publisher offers it (so chunks
  published before the recorder started arrive too), and a deep keep-last queue so a
  recorder that falls behind buffers instead of dropping.
"""
from __future__ import annotations

import re

from machine_ctrl import msgdefs
from machine_ctrl.bag import BagWriter

DEFAULT_EXCLUDED = ('/rosout', '/parameter_events')
# assumed: 1e6 queued messages (~300 MB of JointState) is more backlog than a recorder
# falling behind the 10 kHz graph builds up in any run we make; the queue only holds what
# has not been taken yet.
QUEUE_DEPTH = 1_000_000
_TOPIC = re.compile(r'^/?[A-Za-z_~{][A-Za-z0-9_/{}~]*$')
MACHINE_KEY = 'machine_ctrl.machine'
MACHINE_FILE_KEY = 'machine_ctrl.machine_file'


def parse_topic(text: str) -> tuple[str, str | None]:
    """('/name', 'pkg/msg/Type' or None) from 'NAME' or 'NAME:TYPE'; ValueError otherwise."""
    name, _, type_name = text.partition(':')
    name = name.strip()
    if not _TOPIC.match(name) or name.endswith('/') or '//' in name:
        raise ValueError(f'{text!r} is not a topic name (or NAME:pkg/msg/Type)')
    if not name.startswith('/'):
        name = '/' + name
    return name, (msgdefs.full_name(type_name.strip()) if type_name else None)


def wanted_topics(specs) -> dict[str, str | None]:
    """Topic name -> type (or None: from discovery) for the topic arguments."""
    result: dict[str, str | None] = {}
    for spec in specs:
        name, type_name = parse_topic(spec)
        result[name] = type_name or result.get(name)
    return result


def to_subscribe(available: dict[str, list[str]], wanted: dict | None, excluded, done) -> dict[str, str]:
    """Of the discovered topics (name -> types), those to subscribe now: selected (all but
    the excluded, or the wanted), not yet subscribed, with exactly one type."""
    chosen = {}
    for name, types in available.items():
        if name in done or name in excluded and not (wanted and name in wanted):
            continue
        if wanted is not None and name not in wanted:
            continue
        if len(types) == 1:
            chosen[name] = msgdefs.full_name(types[0])
    return chosen


def subscription_qos(offers: list[dict]) -> dict:
    """Reliability and durability that match every offered profile (rosbag2's adaptation)."""
    reliable = bool(offers) and all(o.get('reliability') == 'reliable' for o in offers)
    transient = bool(offers) and all(o.get('durability') == 'transient_local' for o in offers)
    return {'reliability': 'reliable' if reliable else 'best_effort',
            'durability': 'transient_local' if transient else 'volatile', 'depth': QUEUE_DEPTH}


class Recording:
    """The bag being written plus what the report needs."""

    def __init__(self, directory, custom_data: dict | None = None):
        self.writer = BagWriter(directory)
        self.custom_data = dict(custom_data or {})

    def add_topic(self, name: str, type_name: str, offers) -> None:
        self.writer.add_topic(name, type_name, offers)

    def write(self, topic: str, data: bytes, receive_time_ns: int) -> None:
        self.writer.write(topic, data, receive_time_ns)

    def close(self) -> dict[str, int]:
        return self.writer.close(self.custom_data)

    def report(self) -> str:
        """Per-topic message counts, one line each after a summary line."""
        counts = self.writer.counts()
        lines = [f'recorded {sum(counts.values())} messages on {len(counts)} topics to {self.writer.directory}']
        for name, info in sorted(self.writer.topics.items()):
            lines.append(f'  {name} ({info.type}): {info.count}')
        return '\n'.join(lines)
