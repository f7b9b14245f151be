"""The CDR wire format of the lock-step graph's traffic: sensor_msgs/JointState every step
(/joint_states, /servo_commands, /dual_stage/offsets), trajectory_msgs/JointTrajectory
reference chunks (/reference) and hw_sim's /clock (rosgraph_msgs/Clock, sent only).

Why not rclpy's messages: rclpy builds a Python object for every message and every
trajectory point. Taking a 9-joint JointState costs about 14 us that way and building and
sending one 11 us, against 3-4 us each here; a 500-row reference chunk costs 8.6 ms to take
and 4.1 ms to send, against 0.45 and 0.17 ms here (bench/wire_rate.py). A lock-step step
handles six states, four sent, and a reference row per subscriber, so this is most of
what the Python side of a step costs (bench/RESULTS.md, "Lock-step rates"). Nodes
subscribe to these topics raw and decode the bytes here, and publish bytes encoded here.

The format is the standard one, so any ROS 2 node reads and writes these topics unchanged:
plain CDR (XCDR1, what rmw_fastrtps and rmw_cyclonedds send for ROS 2): a 4-byte
encapsulation header (0 1 0 0: little endian; 0 0 0 0: big endian), then the fields in
order, each aligned to its own size counted from the end of that header; strings are a
uint32 length (NUL included), the bytes and the NUL; sequences a uint32 count and the
elements, doubles aligned to 8 only when there are some.

    JointState      = Header, string[] name, float64[] position, velocity, effort
    JointTrajectory = Header, string[] joint_names, JointTrajectoryPoint[] points
    JointTrajectoryPoint = float64[] positions, velocities, accelerations, effort,
                           Duration time_from_start (int32 sec, uint32 nanosec)
    Header          = Time stamp (int32 sec, uint32 nanosec), string frame_id

Decoding checks every length against the message, so malformed bytes from another node give
:class:`InvalidMessage` with a reason, never a crash. Chunks are decoded with array
operations when every point has the layout of the first (every point the same array
lengths; all our publishers, and the usual case); other chunks raise :class:`NotUniform`
and the caller takes rclpy's decoder. Encoded padding is zero, so equal messages are equal
bytes (rclpy leaves padding uninitialised).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from machine_ctrl import contract
from machine_ctrl.model.errors import InvalidMessage

LITTLE_ENDIAN = b'\x00\x01\x00\x00'
_HEADER = 4                          # encapsulation bytes; alignment counts from here
_STATE_FIELDS = ('position', 'velocity', 'effort')
_POINT_FIELDS = 4                    # positions, velocities, accelerations, effort
_MIN_POINT = 4 * 4 + 8               # bytes of a point with four empty arrays


class NotUniform(InvalidMessage):
    """A chunk whose points differ in layout (array lengths): decode it with rclpy."""


class JointStateData(NamedTuple):
    """A decoded sensor_msgs/JointState (a named tuple: the cheapest object to build)."""
    sec: int
    nanosec: int
    frame_id: str
    name: tuple[str, ...]
    position: tuple[float, ...]
    velocity: tuple[float, ...]
    effort: tuple[float, ...]


class ChunkData(NamedTuple):
    """A decoded trajectory_msgs/JointTrajectory whose points share one layout: per field an
    array (points, length of that field in every point), time_from_start in ns (points,)."""
    sec: int
    nanosec: int
    frame_id: str
    joint_names: tuple[str, ...]
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    time_from_start: np.ndarray


def _pad(offset: int, size: int) -> int:
    """Padding before a field of alignment `size` at absolute byte `offset`."""
    return -(offset - _HEADER) % size


def stamp_ns(data: bytes) -> int:
    """The stamp (ns) that starts a message whose first field is a std_msgs/Header or a
    builtin_interfaces/Time (JointState, Clock, PoseStamped, ...); InvalidMessage if the
    bytes cannot hold one."""
    order = byte_order(data, 'stamped message')
    sec, nanosec = struct.unpack_from(order + 'iI', data, _HEADER)
    return contract.join_ns(sec, nanosec)


_TIME = struct.Struct('<4siI')


def encode_time(sec: int, nanosec: int) -> bytes:
    """A message that is one builtin_interfaces/Time: rosgraph_msgs/Clock (hw_sim's /clock),
    builtin_interfaces/Time itself."""
    return _TIME.pack(LITTLE_ENDIAN, sec, nanosec)


def read_string(data: bytes, offset: int, order: str) -> tuple[bytes, int]:
    """The CDR string at `offset` (before alignment) without its NUL, and the offset after it."""
    offset += _pad(offset, 4)
    (size,) = struct.unpack_from(order + 'I', data, offset)
    end = offset + 4 + size
    if size == 0 or end > len(data):
        raise InvalidMessage(f'string of {size} bytes at byte {offset} does not fit the message')
    return bytes(data[offset + 4:end - 1]), end


def _text(raw: bytes) -> str:
    try:
        return raw.decode()
    except UnicodeDecodeError:
        raise InvalidMessage('a string is not UTF-8') from None


def byte_order(data: bytes, what: str) -> str:
    if len(data) < _HEADER + 8 or data[0] or data[1] > 1 or data[2] or data[3]:
        raise InvalidMessage(f'not a plain CDR {what} (encapsulation header)')
    return '<' if data[1] else '>'


class NamesReader:
    """The header's stamp and frame id and the string[] after it, which both message types
    start with. The strings of the last few blocks seen are kept and reused while a message
    carries the same bytes there (the usual case: each publisher has fixed names;
    /servo_commands has two publishers); any difference, padding included, parses them again."""
    KNOWN = 8                                       # blocks kept (publishers on a topic)

    def __init__(self):
        self._known: list[tuple[bytes, str, tuple[str, tuple[str, ...]]]] = []

    def read(self, data: bytes, order: str) -> tuple[int, int, str, tuple[str, ...], int]:
        """(sec, nanosec, frame_id, names, offset after the names)."""
        sec, nanosec = struct.unpack_from(order + 'iI', data, _HEADER)
        start = _HEADER + 8
        for block, block_order, (frame_id, names) in self._known:
            if block_order == order and data.startswith(block, start):
                return sec, nanosec, frame_id, names, start + len(block)
        frame_id, offset = read_string(data, start, order)
        offset += _pad(offset, 4)
        (count,) = struct.unpack_from(order + 'I', data, offset)
        offset += 4
        if 4 * count > len(data) - offset:         # each string takes >= 4 bytes
            raise InvalidMessage(f'{count} joint names do not fit the message')
        names = []
        for _ in range(count):
            name, offset = read_string(data, offset, order)
            names.append(_text(name))
        parsed = (_text(frame_id), tuple(names))
        self._known = [(bytes(data[start:offset]), order, parsed)] + self._known[:self.KNOWN - 1]
        return sec, nanosec, *parsed, offset


def _names_block(names, frame_id: str) -> bytes:
    """Encoded frame id and string[] names, starting right after the stamp."""
    parts, offset = [], _HEADER + 8

    def put(raw: bytes) -> None:
        nonlocal offset
        parts.append(bytes(_pad(offset, 4)) + raw)
        offset += len(parts[-1])
    put(_string(frame_id))
    put(struct.pack('<I', len(names)))
    for name in names:
        put(_string(name))
    return b''.join(parts)


def _string(text: str) -> bytes:
    raw = text.encode()
    return struct.pack('<I', len(raw) + 1) + raw + b'\x00'


class JointStateDecoder:
    """Decodes the JointStates of one subscription.

    After the names (NamesReader) the arrays: per byte order, offset after the names and
    message length, the layout of the last message seen there is kept as one struct.Struct
    (counts, padding and values), so a message like the one before — every per-step state
    and command — is one unpack and a check of its three counts (a 9-joint state in 1.7 us instead of 3.0 us
    field by field); a count that differs (or a new length) takes the field-by-field path,
    which checks everything and keeps the new layout."""
    KNOWN = 8                                       # layouts kept (publishers on a topic)

    def __init__(self):
        self._names = NamesReader()
        self._layouts: dict[tuple[str, int, int], _ArraysLayout] = {}

    def decode(self, data: bytes) -> JointStateData:
        order = byte_order(data, 'sensor_msgs/JointState')
        try:
            sec, nanosec, frame_id, names, offset = self._names.read(data, order)
            layout = self._layouts.get((order, offset, len(data)))
            if layout is not None:
                values = layout.struct.unpack_from(data, offset)
                (i0, c0), (i1, c1), (i2, c2) = layout.counts
                if values[i0] == c0 and values[i1] == c1 and values[i2] == c2:
                    p, v, e = layout.slices
                    return JointStateData(sec, nanosec, frame_id, names, values[p], values[v], values[e])
            arrays, counts = self._arrays(data, order, offset)
        except struct.error:
            raise InvalidMessage('message ends early') from None
        if len(self._layouts) >= self.KNOWN:
            self._layouts.clear()
        self._layouts[order, offset, len(data)] = _ArraysLayout.of(order, offset, counts)
        return JointStateData(sec, nanosec, frame_id, names, *arrays)

    @staticmethod
    def _arrays(data: bytes, order: str, offset: int) -> tuple[list[tuple[float, ...]], list[int]]:
        """The three arrays from `offset` (right after the names), every length checked."""
        arrays, counts = [], []
        for field in _STATE_FIELDS:
            offset += _pad(offset, 4)
            (count,) = struct.unpack_from(order + 'I', data, offset)
            offset += 4
            counts.append(count)
            if count == 0:
                arrays.append(())
                continue
            offset += _pad(offset, 8)
            if offset + 8 * count > len(data):
                raise InvalidMessage(f'{count} {field} values do not fit the message')
            arrays.append(struct.unpack_from(f'{order}{count}d', data, offset))
            offset += 8 * count
        return arrays, counts


class _ArraysLayout(NamedTuple):
    """The three arrays of a JointState from a given offset: one Struct reading the counts
    (with the padding skipped) and the values, where in its result each count is, the count
    expected there, and the slice of each array."""
    struct: struct.Struct
    counts: tuple[tuple[int, int], ...]
    slices: tuple[slice, ...]

    @classmethod
    def of(cls, order: str, offset: int, counts) -> _ArraysLayout:
        counts_at, slices, item = [], [], 0
        for count in counts:
            counts_at.append((item, count))
            slices.append(slice(item + 1, item + 1 + count))
            item += 1 + count
        return cls(struct.Struct(order + _arrays_format(offset, counts)), tuple(counts_at), tuple(slices))


def _arrays_format(offset: int, counts) -> str:
    """The struct format of a JointState's three arrays from `offset` (right after the names):
    per array its padding and count, then (if any) its padding and values."""
    fmt = []
    for count in counts:
        pad = _pad(offset, 4)
        fmt.append(f'{pad}xI')
        offset += pad + 4
        if count:
            pad = _pad(offset, 8)
            fmt.append(f'{pad}x{count}d')
            offset += pad + 8 * count
    return ''.join(fmt)


class JointStateEncoder:
    """Encodes the JointStates of one publisher: fixed joint names and frame id, a stamp
    and up to three arrays per message (each empty or one value per joint). The whole
    message of each combination of empty and full arrays is one struct.Struct (header,
    stamp, names, counts, zero padding and values): one pack per message (a 9-joint state in
    0.8 us instead of 2.2 us part by part)."""

    def __init__(self, names, frame_id: str = ''):
        self.names = tuple(names)
        self._names_block = _names_block(self.names, frame_id)
        self._names_end = _HEADER + 8 + len(self._names_block)
        self._packers: dict[tuple[int, int, int], struct.Struct] = {}

    def encode(self, sec: int, nanosec: int, position=(), velocity=(), effort=()) -> bytes:
        if isinstance(position, np.ndarray):
            position = position.astype('<f8', copy=False).tolist()
        if isinstance(velocity, np.ndarray):
            velocity = velocity.astype('<f8', copy=False).tolist()
        if isinstance(effort, np.ndarray):
            effort = effort.astype('<f8', copy=False).tolist()
        counts = (len(position), len(velocity), len(effort))
        packer = self._packers.get(counts)
        if packer is None:
            packer = self._packers[counts] = self._packer(counts)
        return packer.pack(LITTLE_ENDIAN, sec, nanosec, self._names_block, counts[0], *position,
                           counts[1], *velocity, counts[2], *effort)

    def _packer(self, counts) -> struct.Struct:
        """The Struct of a message with arrays of these lengths (ValueError unless each is
        0 or one per joint): header, stamp, names, then per array its count and values."""
        for count in counts:
            if count and count != len(self.names):
                raise ValueError(f'{count} values for {len(self.names)} joints')
        return struct.Struct(f'<4siI{len(self._names_block)}s' + _arrays_format(self._names_end, counts))


# -- reference chunks -------------------------------------------------------------------------
@dataclass(frozen=True)
class _PointLayout:
    """Where a point's fields lie, from the point's start: the count and first value of each
    array, time_from_start, and the size. Depends on the point's start, counted from the end
    of the encapsulation header, modulo 8 (`phase`, 0 or 4: everything in a point is a
    multiple of 4 bytes)."""
    count_at: tuple[int, ...]
    values_at: tuple[int, ...]
    duration_at: int
    size: int

    @classmethod
    def of(cls, phase: int, counts) -> _PointLayout:
        count_at, values_at, offset = [], [], 0
        for count in counts:
            count_at.append(offset)
            offset += 4
            if count:
                offset += -(phase + offset) % 8
            values_at.append(offset)
            offset += 8 * count
        return cls(tuple(count_at), tuple(values_at), offset, offset + 8)


def _point_offsets(first: int, points: int, counts):
    """Start offsets of `points` points of one layout from absolute byte `first`, and a
    function giving a field's absolute offsets in every point from its name in _PointLayout
    (and index, for the arrays). A point's phase is its start, counted from the end of the
    encapsulation header, modulo 8 (0 or 4) and the
    next point's is this one's plus its size: the phases are constant, alternate, or change
    once after the first point."""
    if points == 0:
        raise ValueError('a chunk without points')
    layouts = {phase: _PointLayout.of(phase, counts) for phase in (0, 4)}

    def after(phase: int) -> int:
        return (phase + layouts[phase].size) % 8
    p0 = (first - _HEADER) % 8
    p1 = after(p0)
    phases = np.full(points, p1)
    phases[0] = p0
    if p1 != p0 and after(p1) == p0:
        phases[::2] = p0
    sizes = np.where(phases == 0, layouts[0].size, layouts[4].size)
    starts = first + np.concatenate(([0], np.cumsum(sizes[:-1])))

    def field(name: str, k: int | None = None) -> np.ndarray:
        at = [getattr(layouts[p], name) for p in (0, 4)]
        at = [a[k] for a in at] if k is not None else at
        return starts + np.where(phases == 0, at[0], at[1])
    return starts, sizes, field


class ChunkDecoder:
    """Decodes the reference chunks of one subscription."""

    def __init__(self):
        self._names = NamesReader()

    def decode(self, data: bytes) -> ChunkData:
        order = byte_order(data, 'trajectory_msgs/JointTrajectory')
        try:
            sec, nanosec, frame_id, names, offset = self._names.read(data, order)
            offset += _pad(offset, 4)
            (points,) = struct.unpack_from(order + 'I', data, offset)
            first = offset + 4
            if points * _MIN_POINT > len(data) - first:
                raise InvalidMessage(f'{points} points do not fit the message')
            if points == 0:
                empty = np.zeros((0, 0))
                return ChunkData(sec, nanosec, frame_id, names, empty, empty, empty, np.zeros(0, np.int64))
            counts, at = [], first
            for _ in range(_POINT_FIELDS):                 # the first point's array lengths
                (count,) = struct.unpack_from(order + 'I', data, at)
                counts.append(count)
                at += 4
                if count:
                    at += _pad(at, 8) + 8 * count
        except struct.error:
            raise InvalidMessage('message ends early') from None
        starts, sizes, field = _point_offsets(first, points, counts)
        if int(starts[-1] + sizes[-1]) > len(data):     # truncated, or later points are shorter
            raise NotUniform(f'{points} points of {counts[:3]} values do not fit the message')
        words = np.frombuffer(data, order + 'u4', (len(data)) // 4)
        for k, count in enumerate(counts):
            if (words[field('count_at', k) // 4] != count).any():
                raise NotUniform('points with different array lengths')
        doubles = np.frombuffer(data, order + 'f8', (len(data) - _HEADER) // 8, _HEADER)
        arrays = []
        for k in range(3):
            first_value = (field('values_at', k) - _HEADER) // 8
            arrays.append(doubles[first_value[:, None] + np.arange(counts[k])])
        duration = field('duration_at') // 4
        seconds = words[duration].view(order + 'i4').astype(np.int64)
        return ChunkData(sec, nanosec, frame_id, names, *arrays,
                         seconds * contract.NS_PER_SECOND + words[duration + 1].astype(np.int64))


def encode_chunk(sec: int, nanosec: int, names, positions, velocities, accelerations, period_ns: int,
                 frame_id: str = '') -> bytes:
    """A JointTrajectory of rows on the control grid: point i at time_from_start i * period_ns,
    with positions, velocities and accelerations (points, joints) and no effort."""
    rows = [np.asarray(a, '<f8') for a in (positions, velocities, accelerations)]
    points, joints = rows[0].shape
    if any(a.shape != (points, len(names)) for a in rows):
        raise ValueError(f'chunk arrays {[a.shape for a in rows]} do not match {len(names)} joints')
    head = LITTLE_ENDIAN + struct.pack('<iI', sec, nanosec) + _names_block(tuple(names), frame_id)
    head += bytes(_pad(len(head), 4)) + struct.pack('<I', points)
    counts = (joints, joints, joints, 0)
    starts, sizes, field = _point_offsets(len(head), points, counts)
    size = len(head) + int(sizes.sum())
    buffer = bytearray(size + (-size % 8))
    buffer[:len(head)] = head
    words = np.frombuffer(buffer, '<u4')
    doubles = np.frombuffer(buffer, '<f8', offset=_HEADER, count=(len(buffer) - _HEADER) // 8)
    for k, count in enumerate(counts):
        words[field('count_at', k) // 4] = count
        if count:
            first_value = (field('values_at', k) - _HEADER) // 8
            doubles[first_value[:, None] + np.arange(count)] = rows[k]
    duration = field('duration_at') // 4
    offsets = np.arange(points, dtype=np.int64) * period_ns
    words[duration] = (offsets // contract.NS_PER_SECOND).astype('<i4').view('<u4')
    words[duration + 1] = offsets % contract.NS_PER_SECOND
    return bytes(buffer[:size])
