"""McapWriter writes what the mcap package's Writer (default options) writes, byte for byte,
and what it writes reads back through the package's reader."""
import io
import random

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from machine_ctrl.recording.mcap_file import McapWriter


def session(writer, seed: int) -> list[tuple]:
    """The same calls on either writer: schemas and channels between messages, metadata,
    log times that go back, a flush in the middle; the messages written."""
    rng = random.Random(seed)
    writer.start(profile='ros2', library='test library')
    writer.add_metadata('start', {'machine': 'micromill_9axis'})
    schemas = [writer.register_schema(f'pkg/msg/T{i}', 'ros2msg', f'float64 x{i}\n'.encode()) for i in range(2)]
    channels = [writer.register_channel('/a', 'cdr', schemas[0], {'offered_qos_profiles': ''})]
    written = []
    for k in range(3000):
        if k == 700:
            channels.append(writer.register_channel('/b', 'cdr', schemas[1], {'topic_type_hash': 'RIHS01_x'}))
        if k == 1500:
            writer.flush()
        if k == 2000:
            channels.append(writer.register_channel('/c', 'cdr', schemas[0], {}))
        channel = rng.choice(channels)
        log_time = 1_700_000_000_000_000_000 + k * 1000 - rng.randrange(5000)
        data = rng.randbytes(rng.randrange(0, 400))
        writer.add_message(channel, log_time, data, log_time + 7, k)
        written.append((channel, log_time, data, log_time + 7, k))
    writer.add_metadata('rosbag2', {'serialized_metadata': 'version: 9'})
    writer.finish()
    return written


@pytest.mark.parametrize('compression', ['zstd', 'none'])
@pytest.mark.parametrize('chunk_size', [4096, 1024 * 1024])
def test_the_bytes_are_the_mcap_writers(compression, chunk_size):
    theirs, ours = io.BytesIO(), io.BytesIO()
    kind = {'zstd': CompressionType.ZSTD, 'none': CompressionType.NONE}[compression]
    session(Writer(theirs, chunk_size=chunk_size, compression=kind), seed=3)
    session(McapWriter(ours, chunk_size, compression), seed=3)
    assert len(ours.getvalue()) > 100_000
    assert ours.getvalue() == theirs.getvalue()


def test_the_package_reader_reads_every_message_back():
    out = io.BytesIO()
    written = session(McapWriter(out, 4096), seed=5)
    out.seek(0)
    reader = make_reader(out)
    summary = reader.get_summary()
    assert summary.statistics.message_count == len(written)
    assert len(summary.chunk_indexes) > 100                   # many chunks: the indexes are exercised
    read = [(m.channel_id, m.log_time, m.data, m.publish_time, m.sequence)
            for _, _, m in reader.iter_messages(log_time_order=False)]
    assert read == written
    by_time = [m.log_time for _, _, m in reader.iter_messages(log_time_order=True)]
    assert by_time == sorted(w[1] for w in written)            # through the chunk and message indexes
    assert {channel.topic for channel in summary.channels.values()} == {'/a', '/b', '/c'}


def test_unknown_compression_is_refused():
    with pytest.raises(ValueError, match='lz4'):
        McapWriter(io.BytesIO(), compression='lz4')
