"""Crash-safe bags without a graph: what a writer that never closes leaves on disk, and
`machine-ctrl record --recover` of it.

* Truncation at every byte offset of a small bag (chunks of ~300 bytes): the salvage never
  raises, returns exactly the messages of the chunks complete before the cut, in order (a
  prefix of what was written: never more), and the recovery at a sample of those cuts
  gives a bag that the indexed reader, mcap's summary reader and rosbags open.
* Garbage after the cut (a power loss leaves zeros), a flipped bit inside a chunk (its CRC),
  a foreign or empty file.
* The writer's bounds: a chunk is on disk once its oldest message is CHUNK_PERIOD old (fake
  clock) or when it is full; a write that fails (a file size limit: EFBIG, what a full disk
  does too) raises at once and leaves the complete chunks.
* custom_data: the start record comes back, the recorder's loss check is recomputed.
"""
import collections
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml

from machine_ctrl.recording import bag as bagmod
from machine_ctrl.recording import recorder
from machine_ctrl.recording.bag import Bag, BagError, BagWriter, qos_profile

EXE = str(Path(sys.executable).with_name('machine-ctrl'))
PERIOD = 100_000       # ns: the micromill's control period


@pytest.fixture(autouse=True)
def ament(monkeypatch):
    monkeypatch.setenv('AMENT_PREFIX_PATH', sys.prefix)


def joint_state(step: int, names=('x_c', 'y_c')) -> bytes:
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState
    msg = JointState(name=list(names), position=[1e-6 * step] * len(names), effort=[0.5] * len(names))
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(step * PERIOD, 10**9)
    return serialize_message(msg)


def clock(step: int) -> bytes:
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock
    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = divmod(step * PERIOD, 10**9)
    return serialize_message(msg)


def write_bag(directory, steps=40, chunk_size=300, custom_data=None, close=True, skip=()):
    """A bag of /joint_states every step and /clock every 10th; returns (writer, [(topic,
    data, log_time)] in write order)."""
    writer = BagWriter(directory, custom_data=custom_data, chunk_size=chunk_size)
    writer.add_topic('/joint_states', 'sensor_msgs/msg/JointState', [qos_profile(depth=200)])
    writer.add_topic('/clock', 'rosgraph_msgs/msg/Clock', [qos_profile(depth=1000)])
    sent = []
    for step in range(steps):
        if step in skip:
            continue
        sent.append(('/joint_states', joint_state(step), 1_000 + 2 * step))
        if step % 10 == 0:
            sent.append(('/clock', clock(step), 1_001 + 2 * step))
    for topic, data, log_time in sent:
        writer.write(topic, data, log_time)
    if close:
        writer.close({'k': 'v'})
    return writer, sent


class Collect:
    """A salvage sink that keeps (topic, data, log_time) of each message."""

    def __init__(self):
        self.channels, self.messages = {}, []

    def __call__(self, record):
        if isinstance(record, bagmod.Channel):
            self.channels[record.id] = record.topic
        elif isinstance(record, bagmod.Message):
            self.messages.append((self.channels[record.channel_id], record.data, record.log_time))


def salvage(data: bytes):
    import io
    sink = Collect()
    kept, stopped = bagmod._salvage(io.BytesIO(data), len(data), sink)
    return sink.messages, kept, stopped


def chunk_ends(path):
    """(end offset, messages in it) of each chunk, from the complete file's summary."""
    from mcap.reader import make_reader
    with open(path, 'rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        times = [m.log_time for _, _, m in reader.iter_messages()]
    return [(c.chunk_start_offset + c.chunk_length,
             sum(c.message_start_time <= t <= c.message_end_time for t in times)) for c in summary.chunk_indexes]


def test_a_cut_at_every_byte_keeps_exactly_the_complete_chunks(tmp_path):
    _, sent = write_bag(tmp_path / 'b', custom_data={'machine_ctrl.machine': 'micromill_9axis'})
    data = (tmp_path / 'b' / 'b_0.mcap').read_bytes()
    ends = chunk_ends(tmp_path / 'b' / 'b_0.mcap')
    assert len(ends) >= 8 and sum(n for _, n in ends) == len(sent)
    for cut in range(len(bagmod.MAGIC), len(data) + 1):
        messages, kept, _ = salvage(data[:cut])
        expected = sum(n for end, n in ends if end <= cut)
        assert messages == sent[:expected], cut           # a prefix, and all of it
        assert kept <= cut
    for cut in range(len(bagmod.MAGIC)):
        with pytest.raises(BagError, match='not an MCAP file'):
            salvage(data[:cut])


def _recovered_messages(directory):
    with Bag(directory) as bag:
        return [(m.topic, m.data, m.log_time) for m in bag.messages()], bag.custom_data, bag.topics


def test_recovery_at_sampled_cuts_opens_with_every_reader(tmp_path):
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader
    _, sent = write_bag(tmp_path / 'b')
    data = (tmp_path / 'b' / 'b_0.mcap').read_bytes()
    ends = chunk_ends(tmp_path / 'b' / 'b_0.mcap')
    cuts = sorted({end + d for end, _ in ends for d in (-1, 0, 1)} | set(range(8, len(data), 97)))
    for i, cut in enumerate(c for c in cuts if 8 <= c < len(data)):
        directory = tmp_path / f'cut{i}'
        directory.mkdir()
        (directory / 'cut_0.mcap').write_bytes(data[:cut])
        result = recorder.recover(directory)
        expected = sent[:sum(n for end, n in ends if end <= cut)]
        assert result.action == 'recovered' and result.messages == len(expected), cut
        assert result.kept_bytes + result.lost_bytes == cut
        messages, custom_data, _ = _recovered_messages(directory)
        assert messages == expected
        assert (directory / 'cut_0.mcap.damaged').read_bytes() == data[:cut]     # never lost
        with open(directory / 'cut_0.mcap', 'rb') as f:
            summary = make_reader(f).get_summary()
        assert summary.statistics.message_count == len(expected)
        if expected:
            with AnyReader([directory]) as reader:
                counts = {c.topic: c.msgcount for c in reader.connections if c.msgcount}     # topics stay
                assert sum(1 for _ in reader.messages()) == len(expected)
            assert counts == {t: n for t, n in collections.Counter(t for t, _, _ in expected).items()}


def test_zeros_after_the_last_chunk_and_a_flipped_bit_stop_the_salvage_there(tmp_path):
    _, sent = write_bag(tmp_path / 'b')
    data = (tmp_path / 'b' / 'b_0.mcap').read_bytes()
    ends = chunk_ends(tmp_path / 'b' / 'b_0.mcap')
    end, _ = ends[4]
    complete = sum(n for e, n in ends if e <= end)
    # a power loss: the file's length was written, some of its blocks were not
    messages, kept, stopped = salvage(data[:end] + b'\0' * 4096)
    assert messages == sent[:complete] and 'zeros or garbage' in stopped[0]
    # a flipped bit inside the 6th chunk's compressed data: its CRC (or zstd) refuses it
    flipped = bytearray(data)
    flipped[ends[5][0] - 40] ^= 0x10
    messages, kept, stopped = salvage(bytes(flipped))
    assert messages[:complete] == sent[:complete] and len(messages) <= complete + ends[5][1]
    assert len(messages) < len(sent) and 'corrupt' in stopped[0]


def test_the_open_chunk_is_written_once_its_oldest_message_is_chunk_period_old(tmp_path):
    now = [0.0]
    writer = BagWriter(tmp_path / 'b', chunk_period=1.0, clock=lambda: now[0])
    writer.add_topic('/joint_states', 'sensor_msgs/msg/JointState', [])
    path = tmp_path / 'b' / 'b_0.mcap'
    for step in range(5):
        now[0] = 0.2 * step                     # 0 .. 0.8 s: the chunk stays open
        writer.write('/joint_states', joint_state(step), step)
    assert writer.chunks == 0 and salvage(path.read_bytes())[0] == []
    assert not writer.flush_if_due(0.99)
    assert writer.flush_if_due(1.0)           # the recorder's timer: a quiet topic is not held back
    assert len(salvage(path.read_bytes())[0]) == 5 and writer.durable_counts() == {'/joint_states': 5}
    for step in range(5, 9):
        now[0] = 1.0 + 0.3 * (step - 5)         # 1.0 .. 1.9 s
        writer.write('/joint_states', joint_state(step), step)
    assert writer.chunks == 1
    now[0] = 2.0                                # the next write finds the open chunk 1 s old
    writer.write('/joint_states', joint_state(9), 9)
    assert writer.chunks == 2 and len(salvage(path.read_bytes())[0]) == 10
    writer.close()
    with Bag(tmp_path / 'b') as bag:
        assert len(list(bag.messages())) == 10


def test_a_full_chunk_is_on_disk_before_the_writer_returns(tmp_path):
    writer, sent = write_bag(tmp_path / 'b', close=False)        # chunks of 300 bytes
    on_disk, kept, _ = salvage((tmp_path / 'b' / 'b_0.mcap').read_bytes())
    assert writer.chunks >= 8 and on_disk == sent[:len(on_disk)]
    assert len(on_disk) == sum(writer.durable_counts().values()) >= len(sent) - 3
    writer.close()


def _limited_writer(tmp_path, limit):
    """A child process that writes a bag under RLIMIT_FSIZE (what a full disk does: the
    write fails, EFBIG instead of ENOSPC) and prints what it saw."""
    script = textwrap.dedent(f'''
        import resource, signal, sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_bag_recovery import joint_state
        from machine_ctrl.recording.bag import BagWriter, BagError
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit}))
        writer = BagWriter({str(tmp_path / 'b')!r}, custom_data={{'k': 'v'}}, chunk_size=2000)
        writer.add_topic('/joint_states', 'sensor_msgs/msg/JointState', [])
        for step in range(100000):
            try:
                writer.write('/joint_states', joint_state(step), step)
            except BagError as exc:
                print('failed at', step, writer.durable_counts()['/joint_states'], exc)
                break
        try:
            writer.write('/joint_states', joint_state(0), 0)
        except BagError as exc:
            print('refused', exc)
        print('closed', writer.close())
    ''')
    return subprocess.run([sys.executable, '-c', script], capture_output=True, text=True, timeout=120,
                          env={**os.environ, 'AMENT_PREFIX_PATH': sys.prefix})


def test_a_failing_write_raises_at_once_and_keeps_the_complete_chunks(tmp_path):
    done = _limited_writer(tmp_path, 50_000)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    failed = next(line for line in lines if line.startswith('failed at'))
    durable = int(failed.split()[3])
    assert 'writing failed: File too large (EFBIG)' in failed
    assert any(line.startswith('refused') and 'not writable any more' in line for line in lines)
    path = tmp_path / 'b' / 'b_0.mcap'
    size = path.stat().st_size
    assert size <= 50_000
    messages, kept, stopped = salvage(path.read_bytes())
    assert len(messages) == durable > 0 and kept == size and stopped == ()   # cut after the last chunk
    result = recorder.recover(tmp_path / 'b')
    assert result.messages == durable
    assert _recovered_messages(tmp_path / 'b')[1]['k'] == 'v'


def test_recovery_restores_the_start_custom_data_and_recomputes_the_loss_check(tmp_path, micromill):
    start = {recorder.MACHINE_KEY: micromill.name, recorder.MACHINE_FILE_KEY: str(micromill.yaml_path),
             recorder.NAMESPACE_KEY: ''}
    writer, sent = write_bag(tmp_path / 'b', steps=60, close=False, custom_data=start, skip=(12, 13, 30))
    shutil.copytree(tmp_path / 'b', tmp_path / 'crashed')
    result = recorder.recover(tmp_path / 'crashed')
    _, custom_data, _ = _recovered_messages(tmp_path / 'crashed')
    assert {k: v for k, v in custom_data.items() if k != bagmod.RECOVERED_KEY} == {
        **start, 'machine_ctrl.lost/joint_states': '3', 'machine_ctrl.stamps_back/joint_states': '0',
        'machine_ctrl.lost/clock': '1', 'machine_ctrl.stamps_back/clock': '0'}     # /clock 30 was skipped too
    assert custom_data[bagmod.RECOVERED_KEY].startswith(f'{result.messages} messages, the file up to byte')
    assert 'from the start record' in result.custom_data_from and 'recomputed' in result.custom_data_from
    info = yaml.safe_load((tmp_path / 'crashed' / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['custom_data'] == custom_data and info['message_count'] == result.messages
    assert info['relative_file_paths'] == ['b_0.mcap']         # the file keeps its name
    # a closed bag keeps the custom_data of its close (the start record changes nothing)
    writer.close({**start, 'extra': '1'})
    with Bag(tmp_path / 'b') as bag:
        assert bag.custom_data == {**start, 'extra': '1'}


def test_a_bag_without_a_start_record_says_its_custom_data_is_lost(tmp_path):
    write_bag(tmp_path / 'b', close=False)
    result = recorder.recover(tmp_path / 'b')
    assert result.custom_data_from.startswith('lost')
    assert set(_recovered_messages(tmp_path / 'b')[1]) == {bagmod.RECOVERED_KEY}


def _cli(*args):
    return subprocess.run([EXE, *args], capture_output=True, text=True, timeout=120,
                          env={**os.environ, 'AMENT_PREFIX_PATH': sys.prefix})


def test_record_recover_prints_what_was_recovered_and_lost_and_is_idempotent(tmp_path):
    _, sent = write_bag(tmp_path / 'b', steps=200, chunk_size=2000)
    data = (tmp_path / 'b' / 'b_0.mcap').read_bytes()
    ends = chunk_ends(tmp_path / 'b' / 'b_0.mcap')
    cut = (ends[2][0] + ends[3][0]) // 2                        # inside the 4th chunk
    bag = tmp_path / 'crashed'
    bag.mkdir()
    (bag / 'crashed_0.mcap').write_bytes(data[:cut])
    refused = _cli('analyze', str(bag))
    assert refused.returncode == 2 and 'record --recover' in refused.stderr
    done = _cli('record', '--recover', str(bag))
    assert done.returncode == 0, done.stderr
    kept = sum(n for _, n in ends[:3])
    counts = collections.Counter(t for t, _, _ in sent[:kept])
    assert f'recovered {kept} messages on 2 topics' in done.stdout
    assert f'  /joint_states (sensor_msgs/msg/JointState): {counts["/joint_states"]}' in done.stdout
    lost = next(line for line in done.stdout.splitlines() if line.startswith('lost: '))
    lost_bytes, kept_bytes = int(lost.split()[1]), int(lost.split()[5])
    assert lost_bytes + kept_bytes == cut and ends[2][0] <= kept_bytes < ends[3][0]    # + message indexes
    assert 'an incomplete Chunk record' in lost and 'bytes before compression' in lost
    again = _cli('record', '--recover', str(bag))
    assert again.returncode == 0 and 'nothing to recover' in again.stdout
    (bag / 'metadata.yaml').unlink()
    rebuilt = _cli('record', '--recover', str(bag))
    assert rebuilt.returncode == 0 and 'metadata.yaml rebuilt' in rebuilt.stdout
    assert _recovered_messages(bag)[0] == sent[:kept]


def test_record_recover_refuses_with_one_line(tmp_path):
    (tmp_path / 'text').mkdir()
    (tmp_path / 'text' / 'text_0.mcap').write_text('hello, not a bag\n')
    (tmp_path / 'empty').mkdir()
    (tmp_path / 'empty' / 'empty_0.mcap').write_bytes(b'')
    for path, text in ((tmp_path / 'missing', 'no such bag'), (tmp_path / 'text', 'not an MCAP file'),
                       (tmp_path / 'empty', 'empty file, nothing to recover')):
        done = _cli('record', '--recover', str(path))
        assert done.returncode == 2 and len(done.stderr.splitlines()) == 1 and text in done.stderr, done.stderr
    write_bag(tmp_path / 'b', close=False)
    (tmp_path / 'b' / 'b_0.mcap.damaged').write_bytes(b'earlier')
    done = _cli('record', '--recover', str(tmp_path / 'b'))
    assert done.returncode == 2 and 'an earlier recovery kept the damaged file' in done.stderr
    assert (tmp_path / 'b' / 'b_0.mcap.damaged').read_bytes() == b'earlier'
    usage = _cli('record', '--recover', str(tmp_path / 'b'), '--machine', 'micromill_9axis')
    assert usage.returncode == 2 and 'takes no other argument' in usage.stderr
