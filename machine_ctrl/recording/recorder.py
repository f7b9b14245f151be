"""Recording core (no rclpy): which topics to record, with which subscription QoS, and the
bag they go to. :mod:`machine_ctrl.ros.recorder_node` wires it to the ROS graph.

* Topics: every topic of the graph except ``/rosout`` and ``/parameter_events`` (ROS's log
  and parameter traffic, noise for analysis; name them to record them) and the recorder's own
  progress, or the named ones.
  A name may carry its type, ``/joint_states:sensor_msgs/msg/JointState``: such a topic is
  subscribed at once, before any publisher exists, so nothing its first publisher sends is
  missed; others are subscribed when discovery first sees a publisher.
* QoS (rosbag2's rule): reliable unless some publisher offers only best effort (a reliable
  reader would not match it), transient local when every publisher offers it (so chunks
  published before the recorder started arrive too), and a deep keep-last queue so a
  recorder that falls behind buffers instead of dropping. Fast DDS keeps only ~5000 samples
  per reader whatever the depth, so that buffer is finite: see "Progress".
* Progress (flow control): a stamp up to which every per-step stream has been written
  (:class:`Progress`), published on ``/recorder/progress`` (builtin_interfaces/Time) at
  start (the stamp of step -1: nothing yet), after every ``PROGRESS_EVERY``-th state and whenever newer on a
  short timer. hw_sim with ``recorder_window`` > 0 holds the lock-step graph while it is
  too far ahead of it.
* Loss check: with the machine known, /joint_states (one per control step) and /clock (on a
  grid of its own) are checked for skipped stamps (:class:`StampGaps`); the counts go into
  the report and the bag's custom_data.
* Crash safety: the bag (:class:`machine_ctrl.recording.bag.BagWriter`) holds every chunk
  completed before a kill (a chunk: at most ``bag.CHUNK_PERIOD`` s or ``bag.CHUNK_SIZE``
  bytes of messages); the custom_data known at start (machine, namespace) is in the file
  from the start. :func:`recover` rebuilds such a bag and recomputes the loss check from
  the messages it kept. A write that fails (disk full, file size limit, I/O error) stops
  the recording (:attr:`Recording.stopped`): the bag keeps its complete chunks and needs
  :func:`recover`; the report says so.
"""
from __future__ import annotations

import math
import re
import struct

from machine_ctrl import contract
from machine_ctrl.recording import cdr
from machine_ctrl.recording import msgdefs
from machine_ctrl.recording import bag
from machine_ctrl.recording.bag import BagError, BagWriter
from machine_ctrl.model.config import load_machine
from machine_ctrl.model.errors import ConfigError, InvalidMessage



def default_excluded(namespace: str = '') -> tuple[str, ...]:
    """ROS's log and parameter traffic, and our own flow-control reports."""
    return contract.ROSOUT, contract.PARAMETER_EVENTS, contract.RECORDER_PROGRESS.full(namespace)


# assumed: a report every 10 states costs the recorder < 1 % (one small publish per ~40
# messages of the graph) and keeps hw_sim's view of it at most 10 steps (+ transit) stale,
# small beside the windows that make sense (~100 steps: README).
PROGRESS_EVERY = 10
PROGRESS_PERIOD = 0.005    # s (wall): a newer progress goes out at least this often


def progress_stream_topics(namespace: str = '') -> tuple[str, ...]:
    """The per-step topics of the machine_ctrl graph; each publisher on them is a stream
    (Progress)."""
    return tuple(topic.full(namespace) for topic in contract.PER_STEP_TOPICS)


# assumed: DDS repairs a lost sample within a few seconds (the writers' periodic heartbeat,
# 3 s by default in Fast DDS); a stream silent for longer has lost its publisher (a node
# that left) and must no longer hold the graph.
STREAM_SILENCE = 10.0      # s (wall)
# assumed: 1e6 queued messages (~300 MB of JointState) is more backlog than a recorder
# falling behind the 10 kHz graph builds up in any run we make; the queue only holds what
# has not been taken yet.
QUEUE_DEPTH = 1_000_000
_TOPIC = re.compile(r'^/?[A-Za-z_~{][A-Za-z0-9_/{}~]*$')
MACHINE_KEY = 'machine_ctrl.machine'
MACHINE_FILE_KEY = 'machine_ctrl.machine_file'
NAMESPACE_KEY = 'machine_ctrl.namespace'        # the graph's namespace ('' for the root)
LOST_KEY = 'machine_ctrl.lost'                  # + topic name: messages lost (stamp gaps)
STAMPS_BACK_KEY = 'machine_ctrl.stamps_back'    # + topic name: stamps that went back
SESSION_KEY = 'machine_ctrl.session.'           # + a fact's key: how the recorded graph ran


def session_data(facts) -> dict[str, str]:
    """custom_data entries of KEY=VALUE facts (contract.session_fact; ValueError naming a
    bad one; a key given twice keeps its last value)."""
    entries = {}
    for fact in facts:
        key, value = contract.session_fact(fact)
        entries[SESSION_KEY + key] = value
    return entries


def session_of(custom_data: dict) -> dict[str, str]:
    """The session facts of a bag's custom_data, KEY -> VALUE ({} for a bag without)."""
    return {key[len(SESSION_KEY):]: value for key, value in custom_data.items() if key.startswith(SESSION_KEY)}


def namespace_of(custom_data: dict) -> str:
    """The namespace of the graph a bag recorded ('' for the root, and for bags without it)."""
    return custom_data.get(NAMESPACE_KEY, '')


def parse_topic(text: str, namespace: str = '') -> tuple[str, str | None]:
    """('/ns/name', 'pkg/msg/Type' or None) from 'NAME' or 'NAME:TYPE' (a relative NAME is
    in `namespace`, as ROS resolves it); ValueError otherwise."""
    name, _, type_name = text.partition(':')
    name = name.strip()
    if not _TOPIC.match(name) or name.endswith('/') or '//' in name:
        raise ValueError(f'{text!r} is not a topic name (or NAME:pkg/msg/Type)')
    return contract.absolute(name, namespace), (msgdefs.full_name(type_name.strip()) if type_name else None)


def wanted_topics(specs, namespace: str = '') -> dict[str, str | None]:
    """Topic name -> type (or None: from discovery) for the topic arguments."""
    result: dict[str, str | None] = {}
    for spec in specs:
        name, type_name = parse_topic(spec, namespace)
        result[name] = type_name or result.get(name)
    return result


def to_subscribe(available: dict[str, list[str]], wanted: dict | None, excluded, done,
                 namespace: str = '') -> dict[str, str]:
    """Of the discovered topics (name -> types), those to subscribe now: selected (all of
    the `namespace` but the excluded, or the wanted), not yet subscribed, with exactly one
    type. A recorder in a namespace records its own graph, not another machine's."""
    prefix = contract.normal_namespace(namespace) + '/'
    chosen = {}
    for name, types in available.items():
        if name in done or name in excluded and not (wanted and name in wanted):
            continue
        if wanted is not None and name not in wanted or wanted is None and not name.startswith(prefix):
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


def cdr_stamp_ns(data: bytes) -> int | None:
    """cdr.stamp_ns, or None if the bytes cannot hold a stamp."""
    try:
        return cdr.stamp_ns(data)
    except InvalidMessage:
        return None


class StampGaps:
    """Messages lost from a stream published once per grid step, from its stamps alone: a
    stamp n grid steps after the newest one so far means n - 1 lost. A repeated stamp (a
    re-send) is no loss; a stamp that goes back (a restarted publisher, a looped replay) is
    counted and the check goes on from it. ``grid_ns`` None: the grid is the greatest common
    divisor of the increments seen (a stream decimated by an unknown factor; losing every
    other message then goes unnoticed). Stamps off a known grid are counted, not judged."""

    def __init__(self, grid_ns: int | None = None):
        self.grid_ns = grid_ns
        self.newest: int | None = None
        self.span = 0                   # ns, summed over the increments on the grid
        self.increments = 0
        self.gcd = 0
        self.back = 0
        self.unreadable = 0             # messages without a stamp or off the known grid

    def add(self, stamp: int | None) -> None:
        if stamp is None:
            self.unreadable += 1
            return
        delta = 0 if self.newest is None else stamp - self.newest
        if delta < 0:
            self.back += 1
        elif delta > 0 and self.grid_ns and delta % self.grid_ns:
            self.unreadable += 1
        elif delta > 0:
            self.span += delta
            self.increments += 1
            self.gcd = math.gcd(self.gcd, delta)
        self.newest = stamp

    @property
    def lost(self) -> int:
        grid = self.grid_ns or self.gcd
        return self.span // grid - self.increments if grid else 0


def joint_names_key(data: bytes) -> tuple[str, ...]:
    """A CDR sensor_msgs/JointState's header.frame_id and joint names: what tells one
    publisher's states from another's on a shared topic. Only the strings count, never the
    alignment padding between them (rclpy leaves it uninitialised). () if they cannot be
    read."""
    try:
        _, _, frame_id, names, _ = _NAMES.read(data, cdr.byte_order(data, 'sensor_msgs/JointState'))
    except (InvalidMessage, struct.error):
        return ()
    return (frame_id, *names)


_NAMES = cdr.NamesReader()


class Stream:
    """One publisher's stamped per-step messages: the newest stamp written, the grid its
    stamps advance on (gcd of the increments; 0 until two have come) and when it last wrote."""
    __slots__ = ('newest', 'grid', 'seen')

    def __init__(self, stamp: int, now: float):
        self.newest, self.grid, self.seen = stamp, 0, now

    def add(self, stamp: int, now: float) -> None:
        if stamp > self.newest:
            self.grid = math.gcd(self.grid, stamp - self.newest)
        elif stamp < self.newest:                # the publisher started over
            self.grid = 0
        self.newest, self.seen = stamp, now


class Progress:
    """What the recorder reports to hw_sim's flow control: a stamp P such that every
    per-step stream has been written up to about P. A stream is one publisher on one of
    ``topics`` (JointState topics are split by joint names: /servo_commands has one per
    servo node), since DDS delivers each publisher's messages in order: a message awaiting
    a repair holds back that publisher's later ones while other publishers flow on. So P is
    the minimum over the streams of (newest stamp + its grid - one state period): a
    decimated stream (/clock) is complete until its next message is due. A stream
    constrains P once its grid is known and until it has been silent for ``silence`` s (its
    publisher left). P never exceeds the newest /joint_states stamp; before the first it is
    minus one control period (``period_ns``: the stamp of step -1, nothing written; None
    without a known period). Due after every ``every``-th /joint_states message; :meth:`take`
    also serves a timer."""

    def __init__(self, topics=None, every: int = None, silence: float = None, namespace: str = '',
                 period_ns: int | None = None):
        self.nothing = None if period_ns is None else -period_ns
        self.states_topic = contract.JOINT_STATES.full(namespace)
        self.topics = frozenset(progress_stream_topics(namespace) if topics is None else topics) | {self.states_topic}
        self.every = PROGRESS_EVERY if every is None else every
        self.silence = STREAM_SILENCE if silence is None else silence
        self.streams: dict[tuple, Stream] = {}
        self.sent: int | None = None
        self._since_sent = 0

    def written(self, topic: str, joint_state: bool, data: bytes, now: float) -> bool:
        """A message was written; True if a progress report is due now."""
        if topic not in self.topics:
            return False
        stamp = cdr_stamp_ns(data)
        if stamp is not None:
            key = (topic, joint_names_key(data) if joint_state else ())
            stream = self.streams.get(key)
            if stream is None:
                self.streams[key] = Stream(stamp, now)
            else:
                stream.add(stamp, now)
            self._since_sent += topic == self.states_topic
        return self._since_sent >= self.every

    def value(self, now: float) -> int | None:
        states = [s for (topic, _), s in self.streams.items() if topic == self.states_topic]
        if not states:
            return self.nothing
        state = max(states, key=lambda s: s.seen)
        period = state.grid
        complete = [s.newest + s.grid - period for s in self.streams.values()
                    if s.grid and period and now - s.seen < self.silence]
        return min([state.newest, *complete])

    def streams_on(self, topics) -> int:
        """How many streams of `topics` have been written."""
        return sum(topic in topics for topic, _ in self.streams)

    def take(self, now: float) -> int | None:
        """The stamp to publish now, or None if it went out already."""
        self._since_sent = 0
        value = self.value(now)
        if value is None or self.sent == value:
            return None
        self.sent = value
        return value


class LossCheck:
    """The loss check of a recording of the graph in `namespace`: /joint_states on the
    control period's grid (``period_ns``) and /clock on a grid inferred (:class:`StampGaps`);
    nothing without the period."""

    def __init__(self, period_ns: int | None, namespace: str = ''):
        self.gaps = ({contract.JOINT_STATES.full(namespace): StampGaps(period_ns),
                      contract.CLOCK.full(namespace): StampGaps()} if period_ns else {})

    @classmethod
    def of_custom_data(cls, custom_data: dict) -> LossCheck | None:
        """The check of a bag from the custom_data it started with (machine, namespace);
        None if the machine is not named or cannot be loaded here."""
        for name in (custom_data.get(MACHINE_FILE_KEY), custom_data.get(MACHINE_KEY)):
            if name:
                try:
                    config = load_machine(name)
                except (ConfigError, OSError, ValueError):
                    continue
                return cls(contract.StepClock.of(config).period_ns, namespace_of(custom_data))
        return None

    def add(self, topic: str, data: bytes) -> None:
        gaps = self.gaps.get(topic)
        if gaps is not None:
            gaps.add(cdr_stamp_ns(data))

    def entries(self, recorded) -> dict[str, str]:
        """custom_data entries, per checked topic that was recorded."""
        entries = {}
        for topic, gaps in self.gaps.items():
            if topic in recorded:
                entries[LOST_KEY + topic] = str(gaps.lost)
                entries[STAMPS_BACK_KEY + topic] = str(gaps.back)
        return entries


def recover(path) -> bag.Recovery:
    """:func:`machine_ctrl.recording.bag.recover` of a recorder's bag: the loss check is
    recomputed from the recovered messages when the custom_data written at close is lost
    (the machine is known from the custom_data written at start)."""
    return bag.recover(path, LossCheck.of_custom_data)


class Recording:
    """The bag being written plus what the report needs: the graph of `namespace` (kept in
    the bag's custom_data, from the start). With the machine's control period
    (``period_ns``) the loss check runs on joint_states (grid = the period) and clock (grid
    inferred). ``stopped``: why the recording stopped before its end (a write failed), or
    None."""

    def __init__(self, directory, custom_data: dict | None = None, period_ns: int | None = None,
                 namespace: str = ''):
        self.custom_data = {**(custom_data or {}), NAMESPACE_KEY: contract.normal_namespace(namespace)}
        self.writer = BagWriter(directory, custom_data=self.custom_data)
        self.loss_check = LossCheck(period_ns, namespace)
        self.gaps = self.loss_check.gaps
        self.progress = Progress(namespace=namespace, period_ns=period_ns)
        self.stopped: str | None = None

    def add_topic(self, name: str, type_name: str, offers) -> None:
        self.writer.add_topic(name, type_name, offers)

    def write(self, topic: str, data: bytes, receive_time_ns: int, now: float) -> bool:
        """Write one message (``now``: s, monotonic); True when a progress report is due.
        BagError if the bag cannot be written (the recording has then stopped)."""
        try:
            self.writer.write(topic, data, receive_time_ns)
        except BagError as exc:
            self.stop(str(exc))
            raise
        self.loss_check.add(topic, data)
        return self.progress.written(topic, self.writer.topics[topic].type == contract.JOINT_STATES.type, data, now)

    def flush_if_due(self) -> None:
        """Complete the open chunk if it is old (a timer calls this); BagError as write."""
        try:
            self.writer.flush_if_due()
        except BagError as exc:
            self.stop(str(exc))
            raise

    def stop(self, reason: str) -> None:
        """The recording ends here, before its end (the first reason is kept)."""
        if self.stopped is None:
            self.stopped = reason

    def loss(self) -> dict[str, str]:
        """custom_data entries of the loss check, per checked topic that was recorded."""
        return self.loss_check.entries(self.writer.topics)

    def close(self) -> dict[str, int]:
        """Close the bag (BagError if that fails: the recording is stopped then)."""
        try:
            return self.writer.close({**self.custom_data, **self.loss()})
        except BagError as exc:
            self.stop(str(exc))
            raise

    def report(self) -> str:
        """Per-topic message counts, one line each after a summary line, then the loss check;
        after a failure the counts of what the bag holds, and what to do."""
        failed = self.writer.failure is not None
        counts = self.writer.durable_counts() if failed else self.writer.counts()
        where = 'in the complete chunks of' if failed else 'to'
        lines = [f'recorded {sum(counts.values())} messages on {len(counts)} topics {where} {self.writer.directory}']
        for name, info in sorted(self.writer.topics.items()):
            lines.append(f'  {name} ({info.type}): {counts[name]}')
        checked = [(t, g) for t, g in self.gaps.items() if t in self.writer.topics]
        if not self.gaps:
            lines.append('lost: not checked (no machine given: its control period is unknown)')
        elif checked:
            lines.append('lost (skipped stamps): ' + ', '.join(
                f'{t} {g.lost}' + (f' ({g.back} stamps went back)' if g.back else '')
                + (f' ({g.unreadable} without a stamp on the grid)' if g.unreadable else '') for t, g in checked))
        if self.stopped is not None:
            lines.append(f'recording stopped early: {self.stopped}')
            if failed:
                lines.append(f'the bag has no summary: machine-ctrl record --recover {self.writer.directory} '
                             f'makes it readable (every complete chunk)')
        return '\n'.join(lines)
