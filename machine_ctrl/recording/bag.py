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
  ``rosbag2`` whose ``serialized_metadata`` is the YAML of the bag information.

Reading refuses, with one line (:class:`BagError`), a path that is missing, empty, not
MCAP, truncated (no footer: the writer never closed it), or whose records are corrupt.
"""
from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from machine_ctrl.recording import msgdefs

METADATA_VERSION = 9           # rosbag2 of ROS 2 Jazzy
ROS_DISTRO = 'jazzy'
MAGIC = b'\x89MCAP0\r\n'
LIBRARY = 'machine_ctrl bag writer (python mcap)'
DURATION_INFINITE = {'sec': 9223372036, 'nsec': 854775807}   # RMW_DURATION_INFINITE
CHUNK_SIZE = 1024 * 1024       # bytes of uncompressed messages per chunk (rosbag2's default)


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


class BagWriter:
    """Writes one bag directory. ``add_topic`` before the first ``write`` on a topic;
    ``close`` writes the summary and metadata.yaml (a bag never closed has no footer and is
    refused by the reader as truncated)."""

    def __init__(self, directory, compression: str = 'zstd'):
        self.directory = Path(directory)
        if self.directory.exists() and (not self.directory.is_dir() or any(self.directory.iterdir())):
            raise BagError(f'{self.directory}: exists and is not an empty directory')
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise BagError(f'{self.directory}: cannot create: {exc.strerror}') from None
        self.file_name = f'{self.directory.name}_0.mcap'
        kind = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4, 'none': CompressionType.NONE}[compression]
        self._stream = open(self.directory / self.file_name, 'wb')
        self._writer = Writer(self._stream, chunk_size=CHUNK_SIZE, compression=kind)
        self._writer.start(profile='ros2', library=LIBRARY)
        self.topics: dict[str, TopicInfo] = {}
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self.first_time: int | None = None
        self.last_time: int | None = None
        self.closed = False

    def add_topic(self, name: str, type_name: str, qos_profiles=(), type_hash: str | None = None) -> None:
        """Register a topic (its schema once per type). DefinitionNotFound if the type's
        definition is not installed."""
        if name in self.topics:
            return
        type_name = msgdefs.full_name(type_name)
        if type_name not in self._schemas:
            text = msgdefs.definition(type_name)
            self._schemas[type_name] = self._writer.register_schema(type_name, 'ros2msg', text.encode())
        info = TopicInfo(name, type_name, list(qos_profiles),
                         msgdefs.type_hash(type_name) if type_hash is None else type_hash)
        metadata = {'offered_qos_profiles': _yaml(info.qos_profiles) if info.qos_profiles else '',
                    'topic_type_hash': info.type_hash}
        self._channels[name] = self._writer.register_channel(name, 'cdr', self._schemas[type_name], metadata)
        self.topics[name] = info

    def write(self, topic: str, data: bytes, log_time: int, publish_time: int | None = None) -> None:
        """One serialized message; times in ns (rosbag2: receive and send time, system clock)."""
        info = self.topics[topic]
        info.count += 1
        self._writer.add_message(self._channels[topic], log_time, bytes(data),
                                 log_time if publish_time is None else publish_time, sequence=info.count)
        self.first_time = log_time if self.first_time is None else min(self.first_time, log_time)
        self.last_time = log_time if self.last_time is None else max(self.last_time, log_time)

    def counts(self) -> dict[str, int]:
        return {name: info.count for name, info in self.topics.items()}

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

    def close(self, custom_data: dict | None = None) -> dict[str, int]:
        """Finish the MCAP file (rosbag2 metadata record, summary, footer), write
        metadata.yaml; returns the message count per topic. Idempotent."""
        if not self.closed:
            self.closed = True
            information = self.information(custom_data)
            self._writer.add_metadata('rosbag2', {'serialized_metadata': _yaml(information)})
            self._writer.finish()
            self._stream.close()
            text = _yaml({'rosbag2_bagfile_information': information})
            (self.directory / 'metadata.yaml').write_text(text, encoding='utf-8')
        return self.counts()


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
            raise BagError(f'{self.file}: MCAP file without a summary section; cannot index it')
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
        try:
            for record in self._reader.iter_metadata():
                if record.name == 'rosbag2':
                    loaded = yaml.safe_load(record.metadata.get('serialized_metadata', ''))
                    if isinstance(loaded, dict):
                        return loaded
        except (McapError, struct.error, ValueError, yaml.YAMLError):
            pass
        metadata = self.file.parent / 'metadata.yaml'
        try:
            loaded = yaml.safe_load(metadata.read_text(encoding='utf-8'))
            return loaded.get('rosbag2_bagfile_information', {}) if isinstance(loaded, dict) else {}
        except (OSError, yaml.YAMLError):
            return {}

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
            raise BagError(f'{path}: truncated MCAP file (no footer; the writer did not close it)')
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
