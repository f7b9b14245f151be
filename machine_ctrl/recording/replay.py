"""Replay core (no rclpy): which messages of a bag go out when, and the /clock they carry.

Timing: a message logged at t (bag log time, ns) is due ``(t - t0) / rate`` s of wall time
after the replay started, t0 being the log time of the first replayed message (after
``start_offset`` s into the bag). /clock: a bag's own /clock messages (hw_sim's sim time)
are replayed when they move time forward — resends of the same stamp are dropped — so the
published clock is strictly increasing; with ``loop`` every pass after the first adds the
clock span of the bag (plus one clock step) to the stamps. A bag without /clock gets one
derived from its log time, every ``DERIVED_CLOCK_PERIOD`` of bag time.
"""
from __future__ import annotations

import math
import struct

from machine_ctrl import contract
from machine_ctrl.recording import cdr
from machine_ctrl.recording.bag import Bag, BagError, BagMessage

DERIVED_CLOCK_PERIOD = 10_000_000   # ns; assumed: 100 Hz, the usual rate of a bag player's clock


def clock_ns(data: bytes) -> int:
    """Time (ns) carried by a serialized rosgraph_msgs/Clock; ValueError (InvalidMessage) if
    malformed."""
    return cdr.stamp_ns(data)


def clock_bytes(ns: int) -> bytes:
    """A serialized rosgraph_msgs/Clock carrying `ns`."""
    return cdr.LITTLE_ENDIAN + struct.pack('<iI', *contract.split_ns(ns))


def check_options(rate: float, start_offset: float) -> None:
    if not (math.isfinite(rate) and rate > 0):
        raise ValueError(f'rate must be a positive number, got {rate}')
    if not (math.isfinite(start_offset) and start_offset >= 0):
        raise ValueError(f'start offset must be >= 0 s, got {start_offset}')


def select(bag: Bag, topics=None, start_offset: float = 0.0) -> list[BagMessage]:
    """The messages to replay, in log-time order; BagError if none."""
    if topics:
        unknown = [t for t in topics if t not in bag.topics]
        if unknown:
            raise BagError(f'{bag.path}: no topic {", ".join(unknown)} in the bag '
                           f'(it has {", ".join(sorted(bag.topics)) or "none"})')
    first = min((m.log_time for m in bag.messages(topics)), default=None)
    if first is None:
        raise BagError(f'{bag.path}: no messages to replay')
    start = first + contract.seconds_to_ns(start_offset)
    messages = [m for m in bag.messages(topics, start_time=start)]
    if not messages:
        raise BagError(f'{bag.path}: no messages after the start offset of {start_offset:g} s')
    return messages


class ClockSource:
    """Turns replayed messages into the stamps to publish on the clock `topic` (the bag's, or
    derived from the log times; strictly increasing)."""

    def __init__(self, messages: list[BagMessage], topic: str):
        self.topic = topic
        recorded = [clock_ns(m.data) for m in messages if m.topic == topic]
        self.from_bag = bool(recorded)
        values = recorded or [m.log_time for m in messages]
        steps = [b - a for a, b in zip(values, values[1:]) if b > a]
        self.pass_span = max(values) - min(values) + (min(steps) if steps else DERIVED_CLOCK_PERIOD)
        self.last: int | None = None
        self.offset = 0

    def new_pass(self, number: int) -> None:
        self.offset = number * self.pass_span

    def stamp_for(self, message: BagMessage) -> int | None:
        """The clock (ns) to publish when `message` goes out, or None (no clock now)."""
        if self.from_bag:
            if message.topic != self.topic:
                return None
            value = clock_ns(message.data) + self.offset
        else:
            value = message.log_time + self.offset
            if self.last is not None and value - self.last < DERIVED_CLOCK_PERIOD:
                return None
        if self.last is not None and value <= self.last:
            return None
        self.last = value
        return value
