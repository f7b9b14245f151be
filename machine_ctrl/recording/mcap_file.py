"""An MCAP file writer whose message path is one packed header and two appends.

The ``mcap`` package's Writer builds a record object and writes its fields one call at a
time for every message: most of a recorder's Python time per message (bench/RESULTS.md,
"[5/8] Recorder"). This writer keeps that package's file layout
record for record (the same records, order, indexes, summary and CRCs as its Writer with
the default options; test_mcap_file.py compares the bytes) and writes the records that
come once per file or per chunk through the package's own record classes. Only a message
is packed here: its 31-byte record header by one ``struct`` call, appended with its data
to the open chunk, and its (log time, offset) to that chunk's index of its channel.

The methods are the package Writer's that :class:`machine_ctrl.recording.bag.BagWriter`
uses: ``start``, ``register_schema``, ``register_channel``, ``add_metadata``,
``add_message``, ``flush`` (complete the open chunk) and ``finish``. The output is any
object with ``write(bytes)`` and ``tell()``. A chunk and its message indexes go to it in
one ``write`` call.
"""
from __future__ import annotations

import struct
import zlib

import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, Metadata, MetadataIndex, Schema,
                          Statistics, SummaryOffset)

MAGIC = b'\x89MCAP0\r\n'                      # an MCAP file's first and last 8 bytes
# opcode, record length, channel id, sequence, log time, publish time (MCAP spec, "Message")
_MESSAGE = struct.Struct('<BQHIQQ')
_MESSAGE_FIELDS = _MESSAGE.size - 9            # the record's length counts what follows opcode and length
_INDEX = struct.Struct('<BQHI')                # Message Index: opcode, length, channel id, entries' bytes
_FOOTER_HEAD = struct.Struct('<BQQQ')          # what the footer's CRC covers besides the summary


class McapWriter:
    """Writes one MCAP file to `output` in chunks of about `chunk_size` uncompressed bytes
    (a chunk is completed once it holds more), compressed with `compression` ('zstd' or
    'none')."""

    def __init__(self, output, chunk_size: int = 1024 * 1024, compression: str = 'zstd'):
        if compression not in ('zstd', 'none'):
            raise ValueError(f'compression {compression!r}: zstd or none')
        self.output = output
        self.chunk_size = chunk_size
        self.compression = '' if compression == 'none' else compression
        self.schemas: list[Schema] = []
        self.channels: list[Channel] = []
        self.chunk_indexes: list[ChunkIndex] = []
        self.metadata_indexes: list[MetadataIndex] = []
        # of the completed chunks' messages (the statistics; finish completes the last chunk)
        self.channel_counts: dict[int, int] = {}
        self.message_count = 0
        self.start_time = 0                    # 0 before the first, as the package's Writer
        self.end_time = 0
        self.metadata_count = 0
        self._chunk = bytearray()              # the open chunk's records
        self._chunk_index: dict[int, list[int]] = {}   # channel -> log time, offset, log time, ...
        self._chunk_messages = 0
        self._chunk_start = 0
        self._chunk_end = 0

    def _records(self, *records) -> bytes:
        builder = RecordBuilder()
        for record in records:
            record.write(builder)
        return builder.end()

    def start(self, profile: str = '', library: str = '') -> None:
        self.output.write(MAGIC + self._records(Header(profile, library)))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema = Schema(id=len(self.schemas) + 1, name=name, encoding=encoding, data=data)
        self.schemas.append(schema)
        self._append_to_chunk(schema)
        return schema.id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int, metadata: dict) -> int:
        channel = Channel(id=len(self.channels) + 1, topic=topic, message_encoding=message_encoding,
                          schema_id=schema_id, metadata=metadata)
        self.channels.append(channel)
        self._append_to_chunk(channel)
        return channel.id

    def _append_to_chunk(self, record) -> None:
        self._chunk += self._records(record)
        if len(self._chunk) > self.chunk_size:
            self._complete_chunk()

    def add_metadata(self, name: str, data: dict) -> None:
        offset = self.output.tell()
        record = self._records(Metadata(name=name, metadata=data))
        self.output.write(record)
        self.metadata_count += 1
        self.metadata_indexes.append(MetadataIndex(offset=offset, length=len(record), name=name))

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int) -> None:
        chunk = self._chunk
        index = self._chunk_index.get(channel_id)
        if index is None:
            index = self._chunk_index[channel_id] = []
        index += (log_time, len(chunk))
        chunk += _MESSAGE.pack(Opcode.MESSAGE, _MESSAGE_FIELDS + len(data), channel_id, sequence, log_time,
                               publish_time)
        chunk += data
        if not self._chunk_messages:
            self._chunk_start = self._chunk_end = log_time
        elif log_time < self._chunk_start:
            self._chunk_start = log_time
        elif log_time > self._chunk_end:
            self._chunk_end = log_time
        self._chunk_messages += 1
        if len(chunk) > self.chunk_size:
            self._complete_chunk()

    def _complete_chunk(self) -> None:
        """Write the open chunk (if it holds a message) and its message indexes, in one call."""
        if not self._chunk_messages:
            return
        data = bytes(self._chunk)
        chunk = Chunk(message_start_time=self._chunk_start, message_end_time=self._chunk_end,
                      uncompressed_size=len(data), uncompressed_crc=zlib.crc32(data), compression=self.compression,
                      data=zstandard.compress(data) if self.compression else data)
        start = self.output.tell()
        record = self._records(chunk)
        indexes = bytearray()
        offsets = {}
        for channel_id, entries in self._chunk_index.items():
            offsets[channel_id] = start + len(record) + len(indexes)
            indexes += _INDEX.pack(Opcode.MESSAGE_INDEX, 6 + 8 * len(entries), channel_id, 8 * len(entries))
            indexes += struct.pack(f'<{len(entries)}Q', *entries)
            self.channel_counts[channel_id] = self.channel_counts.get(channel_id, 0) + len(entries) // 2
        self.start_time = min(self.start_time, self._chunk_start) if self.message_count else self._chunk_start
        self.end_time = max(self.end_time, self._chunk_end)
        self.message_count += self._chunk_messages
        self.chunk_indexes.append(ChunkIndex(
            message_start_time=chunk.message_start_time, message_end_time=chunk.message_end_time,
            chunk_start_offset=start, chunk_length=len(record), message_index_offsets=offsets,
            message_index_length=len(indexes), compression=chunk.compression, compressed_size=len(chunk.data),
            uncompressed_size=chunk.uncompressed_size))
        self._chunk = bytearray()
        self._chunk_index = {}
        self._chunk_messages = self._chunk_start = self._chunk_end = 0
        self.output.write(record + indexes)

    def flush(self) -> None:
        """Complete the open chunk now (nothing if it holds no message)."""
        self._complete_chunk()

    def statistics(self) -> Statistics:
        return Statistics(message_count=self.message_count, schema_count=len(self.schemas),
                          channel_count=len(self.channels), attachment_count=0, metadata_count=self.metadata_count,
                          chunk_count=len(self.chunk_indexes), message_start_time=self.start_time,
                          message_end_time=self.end_time, channel_message_counts=dict(self.channel_counts))

    def finish(self) -> None:
        """The last chunk, the data end, the summary (schemas, channels, statistics, chunk and
        metadata indexes, their offsets) and the footer. The output stays open."""
        self._complete_chunk()
        self.output.write(self._records(DataEnd(0)))
        summary_start = self.output.tell()
        summary = bytearray()
        offsets = []
        for opcode, group in ((Opcode.SCHEMA, self.schemas), (Opcode.CHANNEL, self.channels),
                              (Opcode.STATISTICS, [self.statistics()]), (Opcode.CHUNK_INDEX, self.chunk_indexes),
                              (Opcode.ATTACHMENT_INDEX, []), (Opcode.METADATA_INDEX, self.metadata_indexes)):
            group_start = len(summary)
            summary += self._records(*group)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + group_start,
                                         group_length=len(summary) - group_start))
        offset_start = summary_start + len(summary)
        summary += self._records(*offsets)
        crc = zlib.crc32(_FOOTER_HEAD.pack(Opcode.FOOTER, 20, summary_start, offset_start), zlib.crc32(summary))
        self.output.write(bytes(summary) + self._records(Footer(summary_start=summary_start,
                                                                summary_offset_start=offset_start,
                                                                summary_crc=crc)) + MAGIC)
