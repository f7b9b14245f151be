"""rosbag2 bag directories with MCAP storage, written and read without rosbag2 (there is none
on PyPI) and without rclpy: serialized CDR bytes in, bytes out.

Layout written (what rosbag2 of ROS 2 Jazzy writes with the mcap storage plugin):

* ``<dir>/metadata.yaml``: ``rosbag2_bagfile_information`` version 9: storage ``mcap``,
  duration, starting time, message counts per topic, topic metadata (name, type,
  ``serialization_format: cdr``, ``offered_qos_profiles`` as a list with policy names, the
  REP-2011 ``type_description_hash``), ``relative_file_paths``, ``files``, ``custom_data``,
  ``ros_distro``.
* ``<dir>/<name>_0.mcap``: profile ``ros2``; one Schema per type (encoding ``ros2msg``, the
  full definition with dependencies, see :mod:`machine_ctrl.recording.msgdefs`); one Channel per topic
  (encoding ``cdr``, metadata ``offered_qos_profiles`` = the YAML text of the profile list and
  ``topic_type_hash``); zstd-compressed chunks with message indexes, the summary (schemas,
  channels, statistics, chunk and metadata indexes, summary offsets) and a Metadata record
  ``rosbag2`` whose ``serialized_metadata`` is the YAML of the bag information. A writer
  given the custom_data it knows at start also writes it at once, as the Metadata record
  ``machine_ctrl.start`` right after the header (:data:`START_METADATA`), so a bag that is
  never closed keeps it.

Crash safety (:class:`BagWriter`): the file is written unbuffered, a whole chunk (and its
message indexes) per write call, so every completed chunk is in the operating system's
hands at once and survives the writer's process being killed. A chunk is completed when
it holds :data:`CHUNK_SIZE` bytes of records or when its oldest message is
:data:`CHUNK_PERIOD` s old (checked on every write and by :meth:`BagWriter.flush_if_due`,
which a recorder calls on a timer). A background thread fsyncs the file after a chunk,
at most every :data:`SYNC_PERIOD` s, so completed chunks also survive a power loss once
synced. What a kill can lose is the open chunk: at most ``CHUNK_PERIOD`` s (plus the
timer's period) or ``CHUNK_SIZE`` bytes of messages, whichever comes first; a power loss
in addition the chunks completed since the last fsync began (at most ``SYNC_PERIOD`` s +
one fsync). Such a bag has no summary: :func:`recover` rebuilds it. A write that fails
(disk full, file too large, I/O error) raises :class:`BagError` at once: the file is cut
back to its last complete record and closed, and the writer refuses everything after.

Reading refuses, with one line (:class:`BagError`), a path that is missing, empty, not
MCAP, truncated (no footer: the writer never closed it), or whose records are corrupt.

Recovery (:func:`recover`, ``machine-ctrl record --recover BAG``, what ``ros2 bag reindex``
does for rosbag2): reads the damaged file record by record up to the first record that is
incomplete or corrupt (a chunk counts only when whole, decompressible and its CRC
matches), writes those schemas, channels and messages into a new complete file (chunks,
indexes, summary, the rosbag2 record) that takes the original's name, keeps the original
as ``<name>.mcap.damaged``, and writes metadata.yaml. The custom_data comes from the
rosbag2 record if it made it to disk, else from the start record (plus what the caller
adds, e.g. the recorder's loss check recomputed), else it is lost and the report says so.
"""
from __future__ import annotations

import contextlib
import errno
import io
import math
import os
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import get_chunk_data_stream

from machine_ctrl import contract
from machine_ctrl.recording import msgdefs
from machine_ctrl.recording.mcap_file import MAGIC, McapWriter

METADATA_VERSION = 9           # rosbag2 of ROS 2 Jazzy
ROS_DISTRO = 'jazzy'
LIBRARY = 'machine_ctrl bag writer (python mcap)'
DURATION_INFINITE = {'sec': 9223372036, 'nsec': 854775807}   # RMW_DURATION_INFINITE
CHUNK_SIZE = 1024 * 1024       # bytes of uncompressed messages per chunk (the mcap package Writer's default)
# assumed: a chunk per second is few enough that compression does not suffer (the graph
# fills 1 MiB in well under a second; a quiet recording gets small chunks), and 1 s is the
# loss a user accepts from a recorder killed outright (README "Recording")
CHUNK_PERIOD = 1.0             # s: a chunk is completed once its oldest message is this old
# measured: an fsync of a 300 KB chunk takes 0.35-0.8 ms on this machine's disk
# (/tmp/fsync_bench.py in the report); once a second is nothing, and the background thread
# keeps a slow disk from stalling the writer
SYNC_PERIOD = 1.0              # s: completed chunks are fsynced at most this often
START_METADATA = 'machine_ctrl.start'    # Metadata record: the custom_data known at start
DAMAGED_SUFFIX = '.damaged'    # recovery keeps the original file under its name + this


class BagError(ValueError):
    """A bag that cannot be written or read; the text is one line naming the path."""


def qos_profile(reliability: str = 'reliable', durability: str = 'volatile', history: str = 'keep_last',
                depth: int = 10, deadline=None, lifespan=None, liveliness: str = 'automatic',
                liveliness_lease_duration=None, avoid_ros_namespace_conventions: bool = False) -> dict:
    """One offered QoS profile as rosbag2 (metadata version 9) stores it: policy names as
    strings, durations as {sec, nsec} (None: infinite)."""
    return {'history': history, 'depth': int(depth), 'reliability': reliability, 'durability': durability,
            'deadline': dict(deadline or DURATION_INFINITE), 'lifespan': dict(lifespan or DURATION_INFINITE),
            'liveliness': liveliness,
            'liveliness_lease_duration': dict(liveliness_lease_duration or DURATION_INFINITE),
            'avoid_ros_namespace_conventions': bool(avoid_ros_namespace_conventions)}


@dataclass
class TopicInfo:
    name: str
    type: str                        # pkg/msg/Type
    qos_profiles: list = field(default_factory=list)
    type_hash: str = ''
    count: int = 0


class _RecordFile:
    """The .mcap file under the :class:`McapWriter`: unbuffered, so what the writer hands
    over (whole records, a chunk and its message indexes in one call) is in the operating
    system's page cache when ``write`` returns, and no user-space buffer is lost when the
    process is killed. Counts its position (the writer asks ``tell``)."""

    def __init__(self, path: Path):
        self.path = path
        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o644)
        self.position = 0

    def write(self, data) -> int:
        view = memoryview(data)
        while view:
            written = os.write(self.fd, view)
            self.position += written
            view = view[written:]
        return len(data)

    def tell(self) -> int:
        return self.position

    def flush(self) -> None:
        """Nothing is buffered here (durability is :class:`_Syncer`'s)."""

    def close(self) -> None:
        if self.fd >= 0:
            fd, self.fd = self.fd, -1
            os.close(fd)


class _Syncer:
    """fsyncs a file descriptor in a background thread when asked, at most every `period` s
    (a request meanwhile is served when the period is over), so the writer never waits for
    the disk. One fsync covers everything written before it began. An fsync error is kept
    in ``error`` and ends the thread; the writer raises it at its next chunk."""

    def __init__(self, fd: int, period: float):
        self.fd, self.period = fd, period
        self.error: OSError | None = None
        self.count, self.total, self.longest = 0, 0.0, 0.0       # fsyncs done, their s in all, the longest
        self._wanted = threading.Event()
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._run, name='bag-fsync', daemon=True)
        self._thread.start()

    def request(self) -> None:
        self._wanted.set()

    def stop(self) -> None:
        """Let an fsync under way finish, then end the thread (the caller closes the fd)."""
        self._stopping.set()
        self._wanted.set()
        self._thread.join()

    def _run(self) -> None:
        last = -math.inf
        while True:
            self._wanted.wait()
            if self._stopping.is_set():
                return
            self._stopping.wait(last + self.period - time.monotonic())    # at most every period
            if self._stopping.is_set():
                return
            self._wanted.clear()
            started = time.monotonic()
            try:
                os.fsync(self.fd)
            except OSError as exc:
                self.error = exc
                return
            took = time.monotonic() - started
            last = started
            self.count, self.total, self.longest = self.count + 1, self.total + took, max(self.longest, took)


class BagWriter:
    """Writes one bag directory. ``add_topic`` before the first ``write`` on a topic;
    ``close`` writes the summary and metadata.yaml (a bag never closed has no footer and is
    refused by the reader as truncated until :func:`recover` rebuilds it).

    ``custom_data`` known at start goes into the file at once (Metadata record
    :data:`START_METADATA`); the custom_data given to ``close`` is the bag's. Completed
    chunks reach the operating system at once and the disk within :data:`SYNC_PERIOD` s;
    a chunk is completed at ``chunk_size`` bytes or once its oldest message is
    ``chunk_period`` s old by ``clock`` (see the module text for what a crash loses). Any
    write error raises :class:`BagError`, after which the writer is ``failure`` (the reason)
    and the file ends with its last complete chunk (:meth:`durable_counts` of messages)."""

    def __init__(self, directory, compression: str = 'zstd', custom_data: dict | None = None, *,
                 chunk_size: int = None, chunk_period: float = None, sync_period: float = None,
                 clock=time.monotonic):
        self.directory = Path(directory)
        if self.directory.exists() and (not self.directory.is_dir() or any(self.directory.iterdir())):
            raise BagError(f'{self.directory}: exists and is not an empty directory')
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise BagError(f'{self.directory}: cannot create: {exc.strerror}') from None
        self._open(f'{self.directory.name}_0.mcap', self.directory / f'{self.directory.name}_0.mcap', compression,
                   custom_data, chunk_size, chunk_period, sync_period, clock)

    @classmethod
    def _recovering(cls, directory: Path, file_name: str, path: Path, custom_data: dict | None) -> BagWriter:
        """A writer of `path` for the bag file `file_name` of `directory` (recovery: the file
        takes its name later), without the empty-directory check."""
        writer = cls.__new__(cls)
        writer.directory = Path(directory)
        writer._open(file_name, path, 'zstd', custom_data, None, math.inf, None, time.monotonic)
        return writer

    def _open(self, file_name: str, path: Path, compression: str, custom_data, chunk_size, chunk_period,
              sync_period, clock) -> None:
        self.file_name = file_name
        self.path = path
        self.chunk_period = CHUNK_PERIOD if chunk_period is None else chunk_period
        self.sync_period = SYNC_PERIOD if sync_period is None else sync_period
        self._clock = clock
        self.topics: dict[str, TopicInfo] = {}
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self.first_time: int | None = None
        self.last_time: int | None = None
        self.closed = False
        self.failure: str | None = None
        self.chunks = 0                       # chunks completed (on the OS's side)
        self._chunk_started: float | None = None  # clock time of the oldest message of the open chunk
        self._good_end = 0                    # bytes of the file that end with a complete record
        self._durable: dict[str, int] = {}    # counts per topic in the completed chunks
        self._syncer: _Syncer | None = None
        try:
            self._file = _RecordFile(path)
        except OSError as exc:
            raise BagError(f'{path}: cannot write: {exc.strerror}') from None
        self._writer = McapWriter(self._file, CHUNK_SIZE if chunk_size is None else chunk_size, compression)
        self._guarded(self._start, custom_data)

    def _start(self, custom_data) -> None:
        self._writer.start(profile='ros2', library=LIBRARY)
        if custom_data:
            self._writer.add_metadata(START_METADATA, {str(k): str(v) for k, v in custom_data.items()})
        self._good_end = self._file.position

    def add_topic(self, name: str, type_name: str, qos_profiles=(), type_hash: str | None = None, *,
                  definition: bytes | None = None, channel_metadata: dict | None = None) -> None:
        """Register a topic (its schema once per type). DefinitionNotFound if the type's
        definition is not installed (recovery passes the recorded `definition` and
        `channel_metadata` instead)."""
        if name in self.topics:
            return
        type_name = msgdefs.full_name(type_name)
        if type_name not in self._schemas:
            text = msgdefs.definition(type_name).encode() if definition is None else definition
            self._schemas[type_name] = self._guarded(self._writer.register_schema, type_name, 'ros2msg', text)
        info = TopicInfo(name, type_name, list(qos_profiles),
                         msgdefs.type_hash(type_name) if type_hash is None else type_hash)
        metadata = channel_metadata if channel_metadata is not None else {
            'offered_qos_profiles': _yaml(info.qos_profiles) if info.qos_profiles else '',
            'topic_type_hash': info.type_hash}
        self._channels[name] = self._guarded(self._writer.register_channel, name, 'cdr', self._schemas[type_name],
                                             metadata)
        self.topics[name] = info

    def write(self, topic: str, data: bytes, log_time: int, publish_time: int | None = None,
              sequence: int | None = None) -> None:
        """One serialized message; times in ns (rosbag2: receive and send time, system clock)."""
        info = self.topics[topic]
        if self.failure is not None:
            raise BagError(f'{self.path}: not writable any more: {self.failure}')
        info.count += 1
        position = self._file.position
        try:
            self._writer.add_message(self._channels[topic], log_time, bytes(data),
                                     log_time if publish_time is None else publish_time,
                                     info.count if sequence is None else sequence)
        except OSError as exc:
            self._fail(exc, 'writing')
        self.first_time = log_time if self.first_time is None else min(self.first_time, log_time)
        self.last_time = log_time if self.last_time is None else max(self.last_time, log_time)
        if self._file.position != position:          # the chunk reached its size: written
            self._chunk_written()
        elif self._chunk_started is None:
            self._chunk_started = self._clock()
        elif self._clock() - self._chunk_started >= self.chunk_period:
            self.flush()

    def flush_if_due(self, now: float | None = None) -> bool:
        """Complete the open chunk if its oldest message is chunk_period s old (a timer of
        the recorder calls this, so a quiet topic is not held back); True if it did."""
        if self._chunk_started is None or self.failure is not None or self.closed:
            return False
        if (self._clock() if now is None else now) - self._chunk_started < self.chunk_period:
            return False
        self.flush()
        return True

    def flush(self) -> None:
        """Complete the open chunk now (written to the file, fsync requested)."""
        if self.failure is not None or self.closed or self._chunk_started is None:
            return
        position = self._file.position
        self._guarded(self._writer.flush)
        if self._file.position != position:
            self._chunk_written()

    def _chunk_written(self) -> None:
        self._good_end = self._file.position
        self._durable = self.counts()
        self._chunk_started = None
        self.chunks += 1
        if self._syncer is None:
            self._syncer = _Syncer(self._file.fd, self.sync_period)
        elif self._syncer.error is not None:
            self._fail(self._syncer.error, 'syncing')
        self._syncer.request()

    def _guarded(self, call, *args):
        """`call(*args)` on the file; an OSError makes the writer fail (BagError)."""
        try:
            return call(*args)
        except OSError as exc:
            self._fail(exc, 'writing')

    def _fail(self, exc: OSError, doing: str) -> None:
        """Keep the complete records (cut the file after the last one), close, raise BagError."""
        self.failure = f'{doing} failed: {_os_error(exc)}'
        if self._syncer is not None:
            self._syncer.stop()
        try:
            os.ftruncate(self._file.fd, self._good_end)
        except OSError:
            pass
        try:
            self._file.close()
        except OSError:
            pass
        raise BagError(f'{self.path}: {self.failure}') from None

    def counts(self) -> dict[str, int]:
        return {name: info.count for name, info in self.topics.items()}

    def durable_counts(self) -> dict[str, int]:
        """Messages per topic in the completed chunks (what a crash now would keep), all of
        them once closed."""
        return self.counts() if self.closed and self.failure is None else {
            name: self._durable.get(name, 0) for name in self.topics}

    def sync_stats(self) -> tuple[int, float, float]:
        """(fsyncs done, their total s, the longest s)."""
        s = self._syncer
        return (s.count, s.total, s.longest) if s is not None else (0, 0.0, 0.0)

    def information(self, custom_data: dict | None) -> dict:
        """The ``rosbag2_bagfile_information`` mapping (metadata version 9)."""
        start = self.first_time or 0
        duration = (self.last_time - start) if self.last_time is not None else 0
        total = sum(info.count for info in self.topics.values())
        return {
            'version': METADATA_VERSION,
            'storage_identifier': 'mcap',
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': total,
            'topics_with_message_count': [
                {'topic_metadata': {'name': i.name, 'type': i.type, 'serialization_format': 'cdr',
                                    'offered_qos_profiles': i.qos_profiles,
                                    'type_description_hash': i.type_hash},
                 'message_count': i.count} for i in self.topics.values()],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [self.file_name],
            'files': [{'path': self.file_name, 'starting_time': {'nanoseconds_since_epoch': start},
                       'duration': {'nanoseconds': duration}, 'message_count': total}],
            'custom_data': {str(k): str(v) for k, v in (custom_data or {}).items()},
            'ros_distro': ROS_DISTRO,
        }

    def close(self, custom_data: dict | None = None, write_metadata: bool = True) -> dict[str, int]:
        """Finish the MCAP file (rosbag2 metadata record, summary, footer), fsync it, write
        metadata.yaml; returns the message count per topic. Idempotent. A writer that failed
        before only returns the counts of its completed chunks; a failure here raises
        BagError (the .mcap is left as complete as it got)."""
        if self.failure is not None:
            self.closed = True
            return self.durable_counts()
        if not self.closed:
            self.closed = True
            information = self.information(custom_data)
            self._guarded(self._writer.add_metadata, 'rosbag2', {'serialized_metadata': _yaml(information)})
            self._guarded(self._writer.finish)
            self._good_end = self._file.position
            if self._syncer is not None:
                self._syncer.stop()
            self._guarded(os.fsync, self._file.fd)
            self._file.close()
            if write_metadata:
                write_metadata_yaml(self.directory, information)
        return self.counts()


def write_metadata_yaml(directory: Path, information: dict) -> None:
    """metadata.yaml of a bag directory, replaced atomically (a crash leaves the old one or
    the new one); BagError naming the file if it cannot be written."""
    path = Path(directory) / 'metadata.yaml'
    temporary = path.with_name('metadata.yaml.writing')
    try:
        with open(temporary, 'w', encoding='utf-8') as f:
            f.write(_yaml({'rosbag2_bagfile_information': information}))
            f.flush()
            os.fsync(f.fileno())
        os.replace(temporary, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise BagError(f'{path}: cannot write: {_os_error(exc)} (the .mcap file is complete; '
                       f'machine-ctrl record --recover {directory} writes it)') from None


def _os_error(exc: OSError) -> str:
    name = errno.errorcode.get(exc.errno or 0)
    return f'{exc.strerror or exc}' + (f' ({name})' if name else '')


class _PlainDumper(yaml.SafeDumper):
    """YAML without anchors/aliases (rosbag2's yaml-cpp writes none)."""

    def ignore_aliases(self, data) -> bool:
        return True


def _yaml(data) -> str:
    return yaml.dump(data, Dumper=_PlainDumper, sort_keys=False, default_flow_style=False)


# -------------------------------------------------------------------------------------------
# reading

@dataclass
class BagMessage:
    topic: str
    type: str
    log_time: int
    data: bytes


class Bag:
    """A bag opened for reading (a bag directory, or one .mcap file). Validated on open."""

    def __init__(self, path):
        self.path = Path(path)
        self.file = _mcap_file(self.path)
        self._stream = open(self.file, 'rb')
        try:
            self._reader = make_reader(self._stream)
            self.summary = self._reader.get_summary()
            header = self._reader.get_header()
        except (McapError, struct.error, ValueError, OSError, EOFError) as exc:
            self._stream.close()
            raise BagError(f'{self.file}: corrupt MCAP file ({_reason(exc)})') from None
        if self.summary is None:
            self._stream.close()
            raise BagError(f'{self.file}: MCAP file without a summary section; cannot index it '
                           f'(machine-ctrl record --recover rebuilds it)')
        if header.profile != 'ros2':
            self._stream.close()
            raise BagError(f'{self.file}: MCAP profile is {header.profile!r}, not ros2')
        self.topics: dict[str, TopicInfo] = {}
        for channel_id, channel in self.summary.channels.items():
            schema = self.summary.schemas.get(channel.schema_id)
            if schema is None or channel.message_encoding != 'cdr' or schema.encoding != 'ros2msg':
                continue
            count = self.summary.statistics.channel_message_counts.get(channel_id, 0) if self.summary.statistics else 0
            self.topics[channel.topic] = TopicInfo(channel.topic, schema.name, [],
                                                   channel.metadata.get('topic_type_hash', ''), count)
        self.information = self._information()

    def _information(self) -> dict:
        """The rosbag2 bag information: from the MCAP ``rosbag2`` metadata record, else from
        metadata.yaml beside the file, else empty."""
        recorded = self.recorded_information()
        if recorded is not None:
            return recorded
        metadata = self.file.parent / 'metadata.yaml'
        try:
            loaded = yaml.safe_load(metadata.read_text(encoding='utf-8'))
            return loaded.get('rosbag2_bagfile_information', {}) if isinstance(loaded, dict) else {}
        except (OSError, yaml.YAMLError):
            return {}

    def recorded_information(self) -> dict | None:
        """The bag information of the MCAP ``rosbag2`` metadata record (None without one)."""
        try:
            for record in self._reader.iter_metadata():
                if record.name == 'rosbag2':
                    loaded = yaml.safe_load(record.metadata.get('serialized_metadata', ''))
                    if isinstance(loaded, dict):
                        return loaded
        except (McapError, struct.error, ValueError, yaml.YAMLError):
            pass
        return None

    @property
    def custom_data(self) -> dict[str, str]:
        data = self.information.get('custom_data') or {}
        return {str(k): str(v) for k, v in data.items()} if isinstance(data, dict) else {}

    def close(self) -> None:
        self._stream.close()

    def __enter__(self) -> Bag:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def messages(self, topics=None, start_time: int | None = None):
        """BagMessage in log-time order (only ``topics`` if given; from ``start_time`` ns)."""
        wanted = None if topics is None else [t for t in topics if t in self.topics]
        try:
            for schema, channel, message in self._reader.iter_messages(topics=wanted, start_time=start_time):
                if channel.topic in self.topics:
                    yield BagMessage(channel.topic, schema.name, message.log_time, message.data)
        except (McapError, struct.error, ValueError, EOFError) as exc:
            raise BagError(f'{self.file}: corrupt MCAP data ({_reason(exc)})') from None


def _reason(exc: Exception) -> str:
    text = ' '.join(str(exc).split()) or type(exc).__name__
    return text[:200]


def _mcap_file(path: Path) -> Path:
    """The .mcap file of a bag path (directory with metadata.yaml or one .mcap, or a file),
    checked for the MCAP magic at both ends."""
    if not path.exists():
        raise BagError(f'{path}: no such bag (file or directory)')
    if path.is_dir():
        path = _file_in_directory(path)
    size = path.stat().st_size
    if size == 0:
        raise BagError(f'{path}: empty file, not an MCAP bag')
    with open(path, 'rb') as f:
        head = f.read(len(MAGIC))
        if head != MAGIC:
            raise BagError(f'{path}: not an MCAP file (no MCAP magic at the start)')
        f.seek(max(size - len(MAGIC), 0))
        if size < 2 * len(MAGIC) or f.read(len(MAGIC)) != MAGIC:
            raise BagError(f'{path}: truncated MCAP file (no footer; the writer did not close it: '
                           f'machine-ctrl record --recover {path} rebuilds it up to its last complete chunk)')
    return path


def _file_in_directory(directory: Path) -> Path:
    metadata = directory / 'metadata.yaml'
    if metadata.is_file():
        try:
            info = (yaml.safe_load(metadata.read_text(encoding='utf-8')) or {}).get('rosbag2_bagfile_information', {})
            files = info.get('relative_file_paths') or []
        except (OSError, yaml.YAMLError, AttributeError):
            raise BagError(f'{metadata}: not a rosbag2 metadata file') from None
        if info.get('storage_identifier') not in (None, 'mcap'):
            raise BagError(f'{metadata}: storage {info.get("storage_identifier")!r} is not mcap')
        if len(files) != 1:
            raise BagError(f'{metadata}: {len(files)} bag files; exactly one .mcap is supported')
        return directory / os.path.basename(str(files[0]))
    found = sorted(directory.glob('*.mcap'))
    if len(found) != 1:
        raise BagError(f'{directory}: no metadata.yaml and {len(found)} .mcap files (need one)')
    return found[0]


# -------------------------------------------------------------------------------------------
# recovery

RECOVERED_KEY = 'machine_ctrl.recovered'     # custom_data of a recovered bag: what was kept and lost


@dataclass
class Recovery:
    """What :func:`recover` found and did. ``action``: 'intact' (nothing to do), 'metadata'
    (the .mcap was complete, metadata.yaml rebuilt) or 'recovered' (a new .mcap from the
    damaged one's complete records, the original kept as ``damaged``)."""
    file: Path
    action: str
    topics: dict[str, TopicInfo]
    kept_bytes: int = 0            # of the damaged file: up to the end of its last complete record
    lost_bytes: int = 0            # after that: an incomplete chunk, a cut summary, garbage
    lost_what: str = ''
    damaged: Path | None = None
    custom_data: dict = field(default_factory=dict)
    custom_data_from: str = ''
    skipped: list[str] = field(default_factory=list)     # what was not carried over, one line each

    @property
    def messages(self) -> int:
        return sum(info.count for info in self.topics.values())

    def report(self) -> str:
        if self.action == 'intact':
            head = f'{self.file}: complete (summary and metadata.yaml readable); nothing to recover'
        elif self.action == 'metadata':
            head = f'{self.file}: complete; metadata.yaml rebuilt'
        else:
            head = (f'recovered {self.messages} messages on {len(self.topics)} topics into {self.file} '
                    f'(every complete chunk; the original is kept as {self.damaged})')
        lines = [head] + [f'  {name} ({info.type}): {info.count}' for name, info in sorted(self.topics.items())]
        if self.action == 'recovered':
            lines.append(f'lost: {self.lost_bytes} bytes after byte {self.kept_bytes}'
                         + (f' ({self.lost_what})' if self.lost_what else '') if self.lost_bytes else
                         'lost: nothing on disk (the file ends with a complete record; what its writer had '
                         'not written yet, its open chunk, never reached the file)')
            lines.extend(f'not carried over: {line}' for line in self.skipped)
        if self.action != 'intact':
            lines.append(f'custom_data: {self.custom_data_from}')
        return '\n'.join(lines)


def recover(path, loss_check=None) -> Recovery:
    """Make the bag at `path` (a bag directory, or its .mcap file) readable by indexed
    readers again, keeping everything up to its last complete chunk (module text).

    `loss_check(custom_data_at_start)` may return an object with ``add(topic, data)`` (fed
    every recovered message in file order) and ``entries(topics) -> dict`` (custom_data
    entries it adds when the bag's own custom_data was lost with its end). BagError (one
    line) when there is nothing to recover from or the result cannot be written; the
    original is never changed, only renamed."""
    file = _recoverable_file(Path(path))
    directory = file.parent
    try:
        with Bag(file) as bag:
            topics = bag.topics
            if _metadata_names(directory, file.name):
                return Recovery(file, 'intact', topics)
            information = bag.recorded_information()
            source = 'from the rosbag2 metadata record in the .mcap'
            if information is None:
                information, source = _information_from_summary(bag), 'none in the .mcap (another writer\'s file)'
    except BagError as exc:
        if 'not ros2' in str(exc):
            raise
        return _rebuild(file, loss_check)
    information['relative_file_paths'] = [file.name]
    for entry in information.get('files') or []:
        entry['path'] = file.name
    try:
        _set_aside(directory / 'metadata.yaml')
    except OSError as exc:
        raise BagError(f'{directory / "metadata.yaml"}: cannot move it aside: {_os_error(exc)}') from None
    write_metadata_yaml(directory, information)
    return Recovery(file, 'metadata', topics, custom_data=information.get('custom_data') or {},
                    custom_data_from=source)


def _recoverable_file(path: Path) -> Path:
    if not path.exists():
        raise BagError(f'{path}: no such bag (file or directory)')
    if path.is_file():
        return path
    try:
        return _file_in_directory(path)
    except BagError:
        found = sorted(path.glob('*.mcap'))
        if len(found) != 1:
            raise BagError(f'{path}: {len(found)} .mcap files (need one)') from None
        return found[0]


def _metadata_names(directory: Path, file_name: str) -> bool:
    """Whether metadata.yaml is readable and names `file_name` as the bag's one file."""
    try:
        info = yaml.safe_load((directory / 'metadata.yaml').read_text(encoding='utf-8'))['rosbag2_bagfile_information']
        return [os.path.basename(str(p)) for p in info['relative_file_paths']] == [file_name]
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return False


def _set_aside(path: Path) -> None:
    """Keep a file about to be replaced as <name>.damaged (unless one is there already)."""
    aside = path.with_name(path.name + DAMAGED_SUFFIX)
    if path.exists() and not aside.exists():
        os.replace(path, aside)


def _information_from_summary(bag: Bag) -> dict:
    """The bag information of a complete file without a rosbag2 record (another writer's)."""
    writer = BagWriter.__new__(BagWriter)
    writer.file_name = bag.file.name
    writer.topics = {}
    for channel in bag.summary.channels.values():
        info = bag.topics.get(channel.topic)
        if info is not None:
            writer.topics[channel.topic] = TopicInfo(info.name, info.type, _profiles(channel.metadata),
                                                     info.type_hash, info.count)
    stats = bag.summary.statistics
    writer.first_time = stats.message_start_time if stats and stats.message_count else None
    writer.last_time = stats.message_end_time if stats and stats.message_count else None
    return writer.information(None)


def _profiles(channel_metadata: dict) -> list:
    try:
        loaded = yaml.safe_load(channel_metadata.get('offered_qos_profiles') or '')
    except yaml.YAMLError:
        return []
    return loaded if isinstance(loaded, list) else []


class _Rebuild:
    """The sink of :func:`_salvage`: writes what it is fed into a new bag file."""

    def __init__(self, file: Path, temporary: Path, loss_check):
        self.file, self.temporary, self.loss_check = file, temporary, loss_check
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, str | None] = {}     # channel id -> topic (None: not carried over)
        self.start: dict | None = None                # custom_data of the start record
        self.final: dict | None = None                # custom_data of the rosbag2 record
        self.writer: BagWriter | None = None
        self.loss = None
        self.skipped: dict[str, int] = {}
        self.last_time: int | None = None

    def open(self) -> BagWriter:
        if self.writer is None:
            self.writer = BagWriter._recovering(self.file.parent, self.file.name, self.temporary, self.start)
            self.loss = self.loss_check(dict(self.start or {})) if self.loss_check is not None else None
        return self.writer

    def skip(self, what: str) -> None:
        self.skipped[what] = self.skipped.get(what, 0) + 1

    def __call__(self, record) -> None:
        if isinstance(record, Message):
            topic = self.channels.get(record.channel_id)
            if topic is None:
                self.skip('messages on channels not carried over or never defined')
                return
            self.writer.write(topic, record.data, record.log_time, record.publish_time, record.sequence)
            self.last_time = record.log_time
            if self.loss is not None:
                self.loss.add(topic, record.data)
        elif isinstance(record, Schema):
            self.schemas[record.id] = record
        elif isinstance(record, Channel):
            self.channel(record)
        elif isinstance(record, Metadata):
            if record.name == START_METADATA and self.writer is None:
                self.start = dict(record.metadata)
            elif record.name == 'rosbag2':
                try:
                    loaded = yaml.safe_load(record.metadata.get('serialized_metadata', ''))
                    data = loaded.get('custom_data') if isinstance(loaded, dict) else None
                except yaml.YAMLError:
                    data = None
                if isinstance(data, dict):
                    self.final = {str(k): str(v) for k, v in data.items()}
            elif record.name != START_METADATA:
                self.skip(f'metadata record {record.name!r}')
        elif isinstance(record, Attachment):
            self.skip(f'attachment {record.name!r}')

    def channel(self, record: Channel) -> None:
        schema = self.schemas.get(record.schema_id)
        writer = self.open()
        if schema is None or record.message_encoding != 'cdr' or schema.encoding != 'ros2msg':
            self.channels[record.id] = None
            self.skip(f'channel {record.topic!r} (not a ROS 2 cdr/ros2msg channel)')
            return
        try:
            type_name = msgdefs.full_name(schema.name)
        except ValueError:
            type_name = None
        known = writer.topics.get(record.topic)
        if type_name is None or known is not None and known.type != type_name:
            self.channels[record.id] = None
            self.skip(f'channel {record.topic!r} of type {schema.name!r}')
            return
        writer.add_topic(record.topic, type_name, _profiles(record.metadata),
                         record.metadata.get('topic_type_hash', ''), definition=schema.data,
                         channel_metadata=dict(record.metadata))
        self.channels[record.id] = record.topic


def _rebuild(file: Path, loss_check) -> Recovery:
    directory = file.parent
    damaged = file.with_name(file.name + DAMAGED_SUFFIX)
    if damaged.exists():
        raise BagError(f'{damaged}: an earlier recovery kept the damaged file here; move it away first')
    temporary = file.with_name(file.name + '.recovering')
    sink = _Rebuild(file, temporary, loss_check)
    try:
        size = file.stat().st_size
        if size == 0:
            raise BagError(f'{file}: empty file, nothing to recover (its writer wrote nothing)')
        with open(file, 'rb') as stream:
            kept, stopped = _salvage(stream, size, sink)
        writer = sink.open()
        topics = set(writer.topics)
        if sink.final is not None:
            custom_data, source = dict(sink.final), 'from the rosbag2 metadata record (complete)'
        elif sink.start is not None:
            entries = sink.loss.entries(topics) if sink.loss is not None else {}
            custom_data = {**sink.start, **entries}
            source = ('from the start record (machine_ctrl.start); the entries written at close are lost'
                      + ('; ' + ', '.join(sorted(entries)) + ' recomputed from the recovered messages'
                         if entries else ''))
        else:
            custom_data, source = {}, 'lost (it is written when a bag is closed, and this bag has no start record)'
        what = _lost_tail(stopped, sink.last_time)
        custom_data[RECOVERED_KEY] = (f'{sum(writer.counts().values())} messages, the file up to byte {kept} of '
                                      f'{size}' + (f'; lost: {what}' if size > kept else ''))
        writer.close(custom_data, write_metadata=False)
        information = writer.information(custom_data)
        os.replace(file, damaged)                   # both renames within the directory: atomic
        os.replace(temporary, file)
        _sync_directory(directory)
        _set_aside(directory / 'metadata.yaml')
        write_metadata_yaml(directory, information)
    except OSError as exc:
        raise BagError(f'{file}: recovery failed: {_os_error(exc)}') from None
    finally:
        if sink.writer is not None and not sink.writer.closed:
            with contextlib.suppress(BagError, OSError):
                sink.writer._file.close()
        with contextlib.suppress(OSError):
            temporary.unlink()
    return Recovery(file, 'recovered', writer.topics, kept, size - kept, what, damaged, custom_data, source,
                    [f'{item} ({n})' for item, n in sink.skipped.items()])


def _sync_directory(directory: Path) -> None:
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


_OPCODE_NAMES = {op.value: op.name.replace('_', ' ').title().replace(' ', '') for op in Opcode}
_SKIPPED_OPCODES = frozenset((Opcode.MESSAGE_INDEX, Opcode.CHUNK_INDEX, Opcode.ATTACHMENT_INDEX,
                              Opcode.METADATA_INDEX, Opcode.STATISTICS, Opcode.SUMMARY_OFFSET))


def _salvage(stream, size: int, sink) -> tuple[int, tuple]:
    """Feed `sink` the records of an MCAP file in order (a chunk's content once the whole
    chunk is read, decompressed and its CRC checked) up to the first record that is
    incomplete or corrupt, or the end of the data section. Returns (the byte offset after
    the last complete record, why it stopped: () at a clean end, else (what, opcode,
    bytes present, record length, the record's first bytes))."""
    if stream.read(len(MAGIC)) != MAGIC:
        raise BagError(f'{getattr(stream, "name", "file")}: not an MCAP file (no MCAP magic at the start)')
    position = len(MAGIC)
    while True:
        prefix = stream.read(9)
        if not prefix:
            return position, ()
        if len(prefix) < 9:
            return position, (f'an incomplete record header ({len(prefix)} of 9 bytes)',)
        opcode, length = struct.unpack('<BQ', prefix)
        name = _OPCODE_NAMES.get(opcode)
        if opcode == 0 or (name is None and opcode < 0x80):
            return position, (f'no MCAP record at byte {position} (opcode 0x{opcode:02x}: zeros or garbage)',)
        present = size - position - 9
        if length > present:
            return position, (f'an incomplete {name or "unknown"} record', opcode, present, length,
                              stream.read(min(present, 64)))
        body = stream.read(length)
        if len(body) < length:
            return position, (f'an incomplete {name or "unknown"} record', opcode, len(body), length, body[:64])
        if position == len(MAGIC) and opcode == Opcode.HEADER:
            try:
                profile = Header.read(ReadDataStream(io.BytesIO(body))).profile
            except Exception:           # noqa: BLE001 - a corrupt header: nothing to salvage
                profile = None
            if profile != 'ros2':
                raise BagError(f'{getattr(stream, "name", "file")}: MCAP profile is {profile!r}, not ros2')
        try:
            records = _parse(opcode, body)
        except Exception as exc:        # noqa: BLE001 - whatever a corrupt record raises ends the salvage
            return position, (f'a corrupt {name} record at byte {position} ({_reason(exc)})',)
        position += 9 + length
        if opcode == Opcode.DATA_END:
            return position, ()          # the data section is whole; what follows is the summary
        for record in records:
            sink(record)


def _parse(opcode: int, body: bytes) -> list:
    """The records one top-level record holds (a chunk's, CRC-checked; index records:
    none, the rebuilt file gets its own)."""
    if opcode in _SKIPPED_OPCODES or opcode not in _OPCODE_NAMES:
        return []
    stream = ReadDataStream(io.BytesIO(body))
    if opcode == Opcode.CHUNK:
        chunk = Chunk.read(stream)
        if stream.count != len(body):
            raise ValueError('chunk length does not match its record')
        data, end = get_chunk_data_stream(chunk, validate_crc=True)     # decompressed, CRC checked
        if end != chunk.uncompressed_size:
            raise ValueError(f'chunk of {end} bytes, {chunk.uncompressed_size} expected')
        records = []
        while data.count < end:                 # as mcap's breakup_chunk
            inner, length = data.read1(), data.read8()
            if data.count + length > end:
                raise ValueError('a record runs past the end of its chunk')
            content = ReadDataStream(io.BytesIO(data.read(length))) if length else None
            if inner == Opcode.MESSAGE:
                records.append(Message.read(content, length))
            elif inner == Opcode.SCHEMA:
                records.append(Schema.read(content))
            elif inner == Opcode.CHANNEL:
                records.append(Channel.read(content))
        return records
    readers = {Opcode.HEADER: Header.read, Opcode.SCHEMA: Schema.read, Opcode.CHANNEL: Channel.read,
               Opcode.METADATA: Metadata.read, Opcode.ATTACHMENT: Attachment.read, Opcode.DATA_END: DataEnd.read,
               Opcode.FOOTER: Footer.read}
    if opcode == Opcode.MESSAGE:
        record = Message.read(stream, len(body))
    else:
        record = readers[opcode](stream)
    if stream.count != len(body) and opcode not in (Opcode.HEADER, Opcode.FOOTER, Opcode.DATA_END):
        raise ValueError(f'record length {len(body)} does not match its content ({stream.count} bytes)')
    return [] if opcode in (Opcode.HEADER, Opcode.FOOTER, Opcode.DATA_END) else [record]


def _lost_tail(stopped: tuple, last_time: int | None) -> str:
    """What the bytes after the last complete record were, in words."""
    if not stopped:
        return ''
    what = stopped[0]
    if len(stopped) < 5:
        return what
    _, opcode, present, length, start = stopped
    what += f' ({present} of {length} bytes)'
    if opcode == Opcode.CHUNK and len(start) >= 24:
        first, last, uncompressed = struct.unpack_from('<QQQ', start)
        span = contract.ns_to_seconds(last - first)
        after = (f', the last {contract.ns_to_seconds(last - last_time):.3f} s after the last recovered message'
                 if last_time else '')
        what += (f': messages logged over {span:.3f} s{after}, {uncompressed} bytes before compression; '
                 f'compressed, they cannot be counted')
    return what
