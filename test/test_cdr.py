"""machine_ctrl.recording.cdr against two independent CDR implementations: rclpy's own (de)serializer
(Fast CDR, little endian) and rosbags' (both byte orders), on seeded random messages; and
malformed bytes, which must give InvalidMessage and nothing else. For reference chunks also
ros_io.parse_chunk_bytes (the nodes' path) against ros_io.parse_chunk on rclpy's message."""
from __future__ import annotations

import collections
import random

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from machine_ctrl.ros import messages as ros_io
from machine_ctrl.recording.cdr import ChunkDecoder, JointStateDecoder, JointStateEncoder, NotUniform, encode_chunk
from machine_ctrl.model.errors import InvalidMessage

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
AXES = ['x_c', 'y_c', 'z_c', 'x_f', 'y_f', 'z_f', 'a_f', 'b_f', 'c_f']


def random_fields(rng: random.Random) -> dict:
    """Names of 0-12 characters (non-ASCII too), 0-6 joints, each array empty or full, any stamp."""
    n = rng.randint(0, 6)
    word = lambda: ''.join(rng.choice('abxyz_/é°') for _ in range(rng.randint(0, 12)))  # noqa: E731
    full = lambda: [rng.uniform(-1e6, 1e6) for _ in range(n)] if rng.random() < 0.6 else []  # noqa: E731
    return {'sec': rng.randint(-2 ** 31, 2 ** 31 - 1), 'nanosec': rng.randint(0, 2 ** 32 - 1),
            'frame_id': word(), 'name': [word() for _ in range(n)],
            'position': full(), 'velocity': full(), 'effort': full()}


def rclpy_message(f: dict) -> JointState:
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id = f['sec'], f['nanosec'], f['frame_id']
    msg.name, msg.position, msg.velocity, msg.effort = f['name'], f['position'], f['velocity'], f['effort']
    return msg


def rosbags_bytes(f: dict, little_endian: bool) -> bytes:
    t = TYPESTORE.types
    msg = t['sensor_msgs/msg/JointState'](
        header=t['std_msgs/msg/Header'](stamp=t['builtin_interfaces/msg/Time'](sec=f['sec'], nanosec=f['nanosec']),
                                        frame_id=f['frame_id']),
        name=f['name'], **{k: np.array(f[k], float) for k in ('position', 'velocity', 'effort')})
    return bytes(TYPESTORE.serialize_cdr(msg, 'sensor_msgs/msg/JointState', little_endian=little_endian))


def decoded_fields(data) -> dict:
    return {'sec': data.sec, 'nanosec': data.nanosec, 'frame_id': data.frame_id, 'name': list(data.name),
            **{k: list(getattr(data, k)) for k in ('position', 'velocity', 'effort')}}


def test_decodes_what_rclpy_and_rosbags_encode():
    rng = random.Random(20261123)
    decoder = JointStateDecoder()              # one decoder: names change between messages
    for _ in range(500):
        f = random_fields(rng)
        assert decoded_fields(decoder.decode(serialize_message(rclpy_message(f)))) == f
        for little in (True, False):
            assert decoded_fields(decoder.decode(rosbags_bytes(f, little))) == f


def test_rclpy_and_rosbags_decode_what_it_encodes():
    rng = random.Random(7)
    for _ in range(500):
        f = random_fields(rng)
        data = JointStateEncoder(f['name'], f['frame_id']).encode(
            f['sec'], f['nanosec'], f['position'], f['velocity'], f['effort'])
        assert deserialize_message(data, JointState) == rclpy_message(f)
        back = TYPESTORE.deserialize_cdr(data, 'sensor_msgs/msg/JointState')
        assert (back.header.stamp.sec, back.header.stamp.nanosec, back.header.frame_id, back.name) == (
            f['sec'], f['nanosec'], f['frame_id'], f['name'])
        assert [back.position.tolist(), back.velocity.tolist(), back.effort.tolist()] == [
            f['position'], f['velocity'], f['effort']]


def test_a_clock_is_the_bytes_rclpy_makes_of_it():
    from builtin_interfaces.msg import Time
    from rosgraph_msgs.msg import Clock
    from machine_ctrl.recording.cdr import encode_time
    for sec, nanosec in ((0, 0), (1, 999_999_999), (-2 ** 31, 2 ** 32 - 1), (2 ** 31 - 1, 123)):
        assert encode_time(sec, nanosec) == serialize_message(Clock(clock=Time(sec=sec, nanosec=nanosec)))
        assert deserialize_message(encode_time(sec, nanosec), Time) == Time(sec=sec, nanosec=nanosec)


def test_a_decoder_reused_on_one_publishers_messages_decodes_each_as_a_fresh_one():
    """The kept layouts (one unpack per message like the one before) against a fresh decoder
    (field by field) and rclpy: the same names, arrays empty or full at random, so messages
    of one length differ in where their counts are (position only, effort only)."""
    rng = random.Random(5)
    reused = JointStateDecoder()
    for _ in range(2000):
        f = random_fields(rng)
        f['name'], f['frame_id'] = AXES[:4], 'base'
        f.update({k: [rng.uniform(-1.0, 1.0) for _ in range(4)] if rng.random() < 0.5 else []
                  for k in ('position', 'velocity', 'effort')})
        data = serialize_message(rclpy_message(f))
        assert decoded_fields(reused.decode(data)) == decoded_fields(JointStateDecoder().decode(data)) == f


def test_equal_messages_are_equal_bytes_and_numpy_input_is_taken():
    encoder = JointStateEncoder(AXES)
    values = np.linspace(-1.0, 1.0, 9)
    assert encoder.encode(3, 4, values, effort=values) == encoder.encode(3, 4, list(values), effort=tuple(values))


def test_encoder_refuses_arrays_of_the_wrong_length():
    with pytest.raises(ValueError, match='8 values for 9 joints'):
        JointStateEncoder(AXES).encode(0, 0, position=[0.0] * 8)


def test_every_truncation_is_refused_with_a_reason():
    data = JointStateEncoder(AXES, 'frame').encode(1, 2, *[np.arange(9.0)] * 3)
    decoder = JointStateDecoder()
    decoder.decode(data)                       # warm the names cache: truncations must still fail
    for end in range(len(data)):
        with pytest.raises(InvalidMessage):
            decoder.decode(data[:end])


def outcomes_of_corruption(data: bytes, take, seed: int) -> collections.Counter:
    """Feed 3000 copies of `data` with 1-4 random bytes changed to `take`: how many it took
    and how many it refused with InvalidMessage; any other error fails the test."""
    rng = random.Random(seed)
    outcomes = collections.Counter()
    for _ in range(3000):
        bad = bytearray(data)
        for _ in range(rng.randint(1, 4)):
            bad[rng.randrange(len(bad))] = rng.randrange(256)
        try:
            take(bytes(bad))
            outcomes['taken'] += 1
        except InvalidMessage:
            outcomes['refused'] += 1
    return outcomes


def test_corrupted_bytes_decode_or_are_refused():
    data = JointStateEncoder(AXES).encode(1, 2, *[np.arange(9.0)] * 3)
    outcomes = outcomes_of_corruption(data, JointStateDecoder().decode, seed=3)
    assert outcomes['taken'] > 0 and outcomes['refused'] > 0, outcomes


@pytest.mark.parametrize('data, reason', [
    (b'', 'encapsulation'),
    (b'\x00\x07\x00\x00' + bytes(40), 'encapsulation'),          # XCDR2: not plain CDR
    (b'\x00\x01\x00\x00' + bytes(8) + b'\xff\xff\xff\x7f', 'does not fit'),   # huge frame_id
    (b'\x00\x01\x00\x00' + bytes(8) + b'\x01\x00\x00\x00\x00\x00\x00\x00' + b'\xff\xff\xff\x0f', 'names do not fit'),
    (b'\x00\x01\x00\x00' + bytes(8) + b'\x01\x00\x00\x00\x00\x00\x00\x00' + b'\x01\x00\x00\x00'
     + b'\x02\x00\x00\x00\xff\x00\x00\x00', 'UTF-8'),
])
def test_malformed_messages_name_the_problem(data, reason):
    with pytest.raises(InvalidMessage, match=reason):
        JointStateDecoder().decode(data)


# -- reference chunks ---------------------------------------------------------------------------
CLOCK = ros_io.StepClock(1e-4)


def random_chunk(rng: random.Random, uniform: bool = True) -> JointTrajectory:
    """0-7 joints, 0-9 points; each array full or empty (the same in every point if uniform),
    effort of any length, any time_from_start."""
    n = rng.randint(0, 7)
    msg = JointTrajectory()
    msg.header.stamp.sec, msg.header.stamp.nanosec = rng.randint(-9, 9), rng.randint(0, 999_999_999)
    msg.header.frame_id = 'w' * rng.randint(0, 3)
    msg.joint_names = [f'j{i}' + 'x' * rng.randint(0, 4) for i in range(n)]
    lengths = [rng.choice([n, 0]) for _ in range(3)] + [rng.randint(0, 3)]
    for _ in range(rng.randint(0, 9)):
        point = JointTrajectoryPoint()
        if not uniform:
            lengths = [rng.choice([n, 0]) for _ in range(3)] + [rng.randint(0, 3)]
        point.positions, point.velocities, point.accelerations, point.effort = (
            [rng.uniform(-1, 1) for _ in range(k)] for k in lengths)
        point.time_from_start.sec, point.time_from_start.nanosec = rng.randint(-3, 3), rng.randint(0, 999_999_999)
        msg.points.append(point)
    return msg


def chunk_fields(msg: JointTrajectory) -> dict:
    return {'stamp': (msg.header.stamp.sec, msg.header.stamp.nanosec), 'frame_id': msg.header.frame_id,
            'names': list(msg.joint_names),
            **{f: [list(getattr(p, f)) for p in msg.points] for f in ('positions', 'velocities', 'accelerations')},
            'time_from_start': [p.time_from_start.sec * 1_000_000_000 + p.time_from_start.nanosec
                                for p in msg.points]}


def decoded_chunk(chunk) -> dict:
    return {'stamp': (chunk.sec, chunk.nanosec), 'frame_id': chunk.frame_id, 'names': list(chunk.joint_names),
            **{f: getattr(chunk, f).tolist() if len(chunk.time_from_start) else []
               for f in ('positions', 'velocities', 'accelerations')},
            'time_from_start': chunk.time_from_start.tolist()}


def test_decodes_chunks_that_rclpy_and_rosbags_encode():
    rng = random.Random(11)
    decoder = ChunkDecoder()
    for _ in range(400):
        msg = random_chunk(rng)
        data = serialize_message(msg)
        assert decoded_chunk(decoder.decode(data)) == chunk_fields(msg)
        assert decoded_chunk(decoder.decode(rosbags_chunk(msg, little_endian=False))) == chunk_fields(msg)


def rosbags_chunk(msg: JointTrajectory, little_endian: bool) -> bytes:
    t = TYPESTORE.types
    time = t['builtin_interfaces/msg/Time']
    duration = t['builtin_interfaces/msg/Duration']
    points = [t['trajectory_msgs/msg/JointTrajectoryPoint'](
        *(np.array(getattr(p, f), float) for f in ('positions', 'velocities', 'accelerations', 'effort')),
        time_from_start=duration(sec=p.time_from_start.sec, nanosec=p.time_from_start.nanosec)) for p in msg.points]
    header = t['std_msgs/msg/Header'](stamp=time(sec=msg.header.stamp.sec, nanosec=msg.header.stamp.nanosec),
                                      frame_id=msg.header.frame_id)
    typed = t['trajectory_msgs/msg/JointTrajectory'](header=header, joint_names=list(msg.joint_names), points=points)
    return bytes(TYPESTORE.serialize_cdr(typed, 'trajectory_msgs/msg/JointTrajectory', little_endian=little_endian))


def test_rclpy_decodes_the_chunks_it_encodes():
    rng = np.random.default_rng(5)
    for _ in range(200):
        points, joints = int(rng.integers(1, 12)), int(rng.integers(0, 10))
        names = [f'a{i}' * int(rng.integers(1, 4)) for i in range(joints)]
        rows = [rng.normal(size=(points, joints)) for _ in range(3)]
        msg = deserialize_message(encode_chunk(7, 123, names, *rows, 100_000, frame_id='w'), JointTrajectory)
        assert chunk_fields(msg) == {
            'stamp': (7, 123), 'frame_id': 'w', 'names': names, 'positions': rows[0].tolist(),
            'velocities': rows[1].tolist(), 'accelerations': rows[2].tolist(),
            'time_from_start': [i * 100_000 for i in range(points)]}
        assert all(len(p.effort) == 0 for p in msg.points)


def test_points_of_different_layouts_are_not_uniform():
    rng = random.Random(2)
    msgs = [m for m in (random_chunk(rng, uniform=False) for _ in range(300))
            if len({tuple(map(len, (p.positions, p.velocities, p.accelerations, p.effort))) for p in m.points}) > 1]
    assert len(msgs) > 50
    for msg in msgs:
        with pytest.raises(NotUniform):
            ChunkDecoder().decode(serialize_message(msg))


def test_every_truncated_chunk_is_refused():
    data = encode_chunk(0, 0, AXES, *[np.ones((5, 9))] * 3, 100_000)
    decoder = ChunkDecoder()
    decoder.decode(data)
    for end in range(len(data)):
        with pytest.raises(InvalidMessage):
            decoder.decode(data[:end])


def test_corrupted_chunks_parse_or_are_refused():
    """Through the nodes' path: our decoder, or rclpy's for what is not uniform."""
    data = encode_chunk(0, 0, AXES, *[np.ones((6, 9))] * 3, 100_000)
    decoder = ChunkDecoder()
    outcomes = outcomes_of_corruption(data, lambda bad: ros_io.parse_chunk_bytes(CLOCK, decoder, bad, AXES), seed=4)
    assert outcomes['taken'] > 0 and outcomes['refused'] > 0, outcomes


def grid_chunk(rows: int, joints=AXES, first_step: int = 40) -> JointTrajectory:
    msg = JointTrajectory()
    msg.header.stamp = CLOCK.stamp(first_step)
    msg.joint_names = list(joints)
    for i in range(rows):
        point = JointTrajectoryPoint()
        point.positions = [0.001 * i + j for j in range(len(joints))]
        point.velocities = [0.1 * i] * len(joints)
        point.time_from_start = CLOCK.duration(i)
        msg.points.append(point)
    return msg


def spoiled(change):
    msg = grid_chunk(6)
    change(msg)
    return msg


def _nan(msg):
    msg.points[3].accelerations = [0.0] * 8 + [float('nan')]


def _mixed(msg):            # not uniform: goes through rclpy, same checks
    msg.points[2].velocities = []
    msg.points[4].positions = [float('inf')] * 9


@pytest.mark.parametrize('msg, reason', [
    (grid_chunk(0), 'no points'),
    (grid_chunk(4, AXES[:8]), 'missing joints c_f'),
    (grid_chunk(4, AXES + ['x_c']), 'duplicate joint names'),
    (spoiled(lambda m: setattr(m.points[2], 'time_from_start', CLOCK.duration(3))), 'point 2 is not at consecutive'),
    (spoiled(lambda m: [setattr(p, 'velocities', [0.0] * 8) for p in m.points]), '8 velocities for 9 joints'),
    (spoiled(_nan), 'point 3 accelerations holds NaN or inf'),
    (spoiled(_mixed), 'point 4 positions holds NaN or inf'),
    (spoiled(lambda m: setattr(m.header.stamp, 'nanosec', 123)), 'not on the 100000 ns control grid'),
])
def test_bad_chunks_are_refused_like_parse_chunk(msg, reason):
    with pytest.raises(InvalidMessage, match=reason):
        ros_io.parse_chunk(CLOCK, msg, AXES)
    with pytest.raises(InvalidMessage, match=reason):
        ros_io.parse_chunk_bytes(CLOCK, ChunkDecoder(), serialize_message(msg), AXES)


@pytest.mark.parametrize('wanted', [AXES, AXES[3:], ['c_f', 'x_c']])
def test_parse_chunk_bytes_equals_parse_chunk(wanted):
    uniform, mixed = grid_chunk(7), grid_chunk(7)
    mixed.points[5].velocities = []
    # the values grid_chunk wrote, by its formula (the mixed chunk's bytes go through parse_chunk
    # itself: these make the comparison not only one parser against the other)
    columns = [AXES.index(name) for name in wanted]
    positions = [[0.001 * i + j for j in columns] for i in range(7)]
    for msg in (uniform, mixed):
        expected = ros_io.parse_chunk(CLOCK, msg, wanted)
        assert ros_io.parse_chunk_bytes(CLOCK, ChunkDecoder(), serialize_message(msg), wanted) == expected
        velocities = [[0.0 if (msg is mixed and i == 5) else 0.1 * i] * len(wanted) for i in range(7)]
        assert expected == (40, positions, velocities, [[0.0] * len(wanted)] * 7)
