"""Bag writer/reader without a graph: schema texts from the installed .msg files, a round
trip of rclpy-serialized messages, and one-line refusals of bad bag files."""
import os
import subprocess
import sys

import pytest

from machine_ctrl.recording import msgdefs
from machine_ctrl.recording.bag import Bag, BagError, BagWriter, qos_profile


@pytest.fixture(autouse=True)
def ament(monkeypatch):
    monkeypatch.setenv('AMENT_PREFIX_PATH', sys.prefix)


def _share(package, name):
    with open(os.path.join(sys.prefix, 'share', package, 'msg', name + '.msg'), encoding='utf-8') as f:
        return f.read()


def test_definition_holds_the_type_and_every_dependency_once():
    text = msgdefs.definition('trajectory_msgs/msg/JointTrajectory')
    parts = text.split('\n' + '=' * 80 + '\n')
    assert parts[0] == _share('trajectory_msgs', 'JointTrajectory')
    deps = {p.split('\n', 1)[0]: p.split('\n', 1)[1] for p in parts[1:]}
    assert deps == {'MSG: std_msgs/Header': _share('std_msgs', 'Header'),
                    'MSG: builtin_interfaces/Time': _share('builtin_interfaces', 'Time'),
                    'MSG: trajectory_msgs/JointTrajectoryPoint': _share('trajectory_msgs', 'JointTrajectoryPoint'),
                    'MSG: builtin_interfaces/Duration': _share('builtin_interfaces', 'Duration')}


def test_unknown_types_are_refused():
    with pytest.raises(msgdefs.DefinitionNotFound):
        msgdefs.definition('no_such_msgs/msg/Thing')
    with pytest.raises(ValueError):
        msgdefs.split_type('not a type')


def _write_joint_states(path, count=5):
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState
    writer = BagWriter(path)
    writer.add_topic('/joint_states', 'sensor_msgs/msg/JointState', [qos_profile(depth=200)])
    sent = []
    for i in range(count):
        msg = JointState(name=['x', 'y'], position=[0.001 * i, -2.5], velocity=[1.0, 2.0], effort=[0.5, i])
        msg.header.stamp.nanosec = 100_000 * i
        sent.append(serialize_message(msg))
        writer.write('/joint_states', sent[-1], 1_000 + i)
    return writer, sent


def test_round_trip_and_readers(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    writer, sent = _write_joint_states(tmp_path / 'b')
    assert writer.close({'k': 'v'}) == {'/joint_states': 5}
    with Bag(tmp_path / 'b') as bag:
        assert [m.data for m in bag.messages()] == sent
        assert bag.custom_data == {'k': 'v'}
        assert bag.topics['/joint_states'].count == 5
    with open(tmp_path / 'b' / 'b_0.mcap', 'rb') as f:
        decoded = [d for *_, d in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]
    assert [list(d.position) for d in decoded] == [[0.001 * i, -2.5] for i in range(5)]
    assert [d.header.stamp.nanosec for d in decoded] == [100_000 * i for i in range(5)]


def test_writer_refuses_a_non_empty_directory(tmp_path):
    (tmp_path / 'x').mkdir()
    (tmp_path / 'x' / 'f').write_text('')
    with pytest.raises(BagError, match='not an empty directory'):
        BagWriter(tmp_path / 'x')


def _analyze(path):
    return subprocess.run([sys.executable, '-m', 'machine_ctrl.app.cli', 'analyze', str(path)],
                          capture_output=True, text=True, env={**os.environ, 'AMENT_PREFIX_PATH': sys.prefix})


def _one_line_error(result, text):
    assert result.returncode == 2
    assert result.stdout == ''
    assert len(result.stderr.splitlines()) == 1, result.stderr
    assert text in result.stderr


def test_truncated_empty_and_foreign_files_give_one_line(tmp_path):
    writer, _ = _write_joint_states(tmp_path / 'b', count=2000)
    writer.close()
    data = (tmp_path / 'b' / 'b_0.mcap').read_bytes()
    (tmp_path / 'cut.mcap').write_bytes(data[: len(data) // 2])
    (tmp_path / 'empty.mcap').write_bytes(b'')
    (tmp_path / 'text.mcap').write_text('hello, not a bag\n')
    corrupt = bytearray(data)
    corrupt[len(data) - 200: len(data) - 100] = b'\xff' * 100        # inside the summary
    (tmp_path / 'corrupt.mcap').write_bytes(bytes(corrupt))
    _one_line_error(_analyze(tmp_path / 'cut.mcap'), 'truncated')
    _one_line_error(_analyze(tmp_path / 'empty.mcap'), 'empty file')
    _one_line_error(_analyze(tmp_path / 'text.mcap'), 'not an MCAP file')
    _one_line_error(_analyze(tmp_path / 'corrupt.mcap'), 'corrupt')
    _one_line_error(_analyze(tmp_path / 'missing'), 'no such bag')


def test_unclosed_bag_is_refused_as_truncated(tmp_path):
    _write_joint_states(tmp_path / 'b')        # never closed: no footer, no metadata.yaml
    with pytest.raises(BagError, match='truncated'):
        Bag(tmp_path / 'b' / 'b_0.mcap')


def test_bag_without_the_needed_topics_gives_one_line(tmp_path):
    writer, _ = _write_joint_states(tmp_path / 'b')
    writer.close({'machine_ctrl.machine': 'micromill_9axis'})
    _one_line_error(_analyze(tmp_path / 'b'), 'no /reference messages')


def test_rosbags_limitation_empty_trailing_sequence():
    """Pinned reader limitation (README): rosbags refuses rclpy's CDR of a message ending in
    an empty float64 sequence, which mcap-ros2-support and rclpy read back."""
    from mcap_ros2._dynamic import generate_dynamic
    from rclpy.serialization import deserialize_message, serialize_message
    from rosbags.typesys import Stores, get_typestore
    from sensor_msgs.msg import JointState
    typestore = get_typestore(Stores.ROS2_JAZZY)
    decode = generate_dynamic('sensor_msgs/msg/JointState', msgdefs.definition('sensor_msgs/msg/JointState'))
    full = serialize_message(JointState(name=['a'], position=[1.0], velocity=[2.0], effort=[3.0]))
    offsets = serialize_message(JointState(name=['a'], position=[1.0]))
    assert typestore.deserialize_cdr(full, 'sensor_msgs/msg/JointState').effort.tolist() == [3.0]
    with pytest.raises(Exception, match='size mismatch'):
        typestore.deserialize_cdr(offsets, 'sensor_msgs/msg/JointState')
    assert list(decode['sensor_msgs/msg/JointState'](offsets).position) == [1.0]
    assert list(deserialize_message(offsets, JointState).position) == [1.0]
