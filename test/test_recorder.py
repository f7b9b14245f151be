"""Recording core without ROS: stamps read from CDR bytes, the loss check on stamp gaps,
when progress goes out, and the loss counts in the report and the bag's custom_data."""
import struct

import pytest

from machine_ctrl import contract
from machine_ctrl.recording import recorder
from machine_ctrl.recording.bag import Bag

PERIOD = 100_000      # ns: the micromill's 100 us


def cdr(stamp_ns: int, little: bool = True, tail: bytes = b'\0' * 8) -> bytes:
    """A CDR message that starts with a stamp (a Header's or a Clock's)."""
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return bytes([0, 1 if little else 0, 0, 0]) + struct.pack('<iI' if little else '>iI', sec, nanosec) + tail


def test_stamp_is_read_from_either_byte_order_and_refused_when_short_or_not_cdr():
    assert recorder.cdr_stamp_ns(cdr(3_000_000_123)) == 3_000_000_123
    assert recorder.cdr_stamp_ns(cdr(-100_000)) == -100_000
    assert recorder.cdr_stamp_ns(cdr(2_500_000_000, little=False)) == 2_500_000_000
    assert recorder.cdr_stamp_ns(cdr(5)[:11]) is None
    assert recorder.cdr_stamp_ns(b'\x00\x07' + cdr(5)[2:]) is None               # unknown encapsulation
    assert recorder.cdr_stamp_ns(bytes([0, 1, 0, 0]) + struct.pack('<iI', 1, 1_000_000_000)) is None


def test_stamp_of_rclpy_serialized_messages():
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    from machine_ctrl.ros.messages import StepClock, joint_state
    stamp = StepClock(1e-4).stamp(12_345)
    assert recorder.cdr_stamp_ns(serialize_message(joint_state(stamp, ['x'], [1.0]))) == 12_345 * PERIOD
    assert recorder.cdr_stamp_ns(serialize_message(Clock(clock=stamp))) == 12_345 * PERIOD
    assert recorder.cdr_stamp_ns(serialize_message(JointState())) == 0


def test_gaps_on_a_known_grid_count_skipped_steps_not_resends_and_note_stamps_going_back():
    gaps = recorder.StampGaps(PERIOD)
    for step in [0, 1, 1, 2, 5, 6, 6, 9, 3, 4, 5]:      # 3, 4 and 7, 8 skipped; then a restart at 3
        gaps.add(step * PERIOD)
    assert gaps.lost == 4 and gaps.back == 1 and gaps.unreadable == 0
    gaps.add(5 * PERIOD + 1)                            # off the grid: counted, not judged
    gaps.add(None)
    assert gaps.lost == 4 and gaps.unreadable == 2


def test_gaps_on_an_inferred_grid():
    gaps = recorder.StampGaps()
    for step in [0, 10, 20, 50, 60]:                    # /clock every 10 steps, 30 and 40 lost
        gaps.add(step * PERIOD)
    assert gaps.lost == 2
    assert recorder.StampGaps().lost == 0


def state(step, names=('x_c', 'y_c', 'z_c'), frame=''):
    from rclpy.serialization import serialize_message

    from machine_ctrl.ros.messages import StepClock, joint_state
    msg = joint_state(StepClock(1e-4).stamp(step), names, [0.1 * step] * len(names), effort=[1.0] * len(names))
    msg.header.frame_id = frame
    return serialize_message(msg)


def test_joint_names_tell_publishers_apart_whatever_the_values():
    key = recorder.joint_names_key
    assert key(state(1)) == key(state(2)) != key(state(1, ('x_f', 'y_f')))
    assert key(state(1, frame='a')) != key(state(1)) and key(state(1, ('x',))) != key(state(1, ('x', 'y')))
    assert key(state(1, frame='workpiece')) == ('workpiece', 'x_c', 'y_c', 'z_c')
    assert key(b'\x00\x01\x00\x00' + b'\x00' * 8 + b'\xff\xff\xff\x7f') == ()     # truncated
    # rclpy leaves CDR padding uninitialised: the key must not depend on it
    padded = bytearray(state(1))
    padded[17:20] = b'\xe5\xa7\x01'                   # frame_id '': length 1 at 12, NUL at 16, 3 padding bytes
    assert key(bytes(padded)) == key(state(1))


def test_progress_goes_out_at_start_every_nth_state_and_on_the_timer_when_newer():
    assert recorder.Progress(every=3).take(0.0) is None             # no period known: nothing to say yet
    progress = recorder.Progress(every=3, period_ns=PERIOD)
    assert progress.take(0.0) == -PERIOD                # start: step -1, nothing written yet
    assert progress.take(0.0) is None
    assert [progress.written('/joint_states', True, state(k), 0.0) for k in range(1, 4)] == [False, False, True]
    assert progress.take(0.0) == 3 * PERIOD
    assert progress.written('/joint_states', True, state(4), 0.0) is False
    assert progress.take(0.0) == 4 * PERIOD             # timer: newer than what went out
    assert progress.take(0.0) is None
    assert progress.written('/joint_states', True, state(4), 0.0) is False and progress.take(0.0) is None
    assert progress.written('/diagnostics', False, cdr(9 * PERIOD), 0.0) is False      # not a stream topic


def test_progress_waits_for_the_slowest_publisher_until_it_falls_silent():
    progress = recorder.Progress(every=1000, silence=5.0)
    coarse, fine = ('x_c', 'y_c', 'z_c'), ('x_f', 'y_f')
    for k in range(21):
        progress.written('/joint_states', True, state(k), 0.0)
        progress.written('/servo_commands', True, state(k, coarse), 0.0)
        if k <= 12:                                     # the fine servo's messages await a repair
            progress.written('/servo_commands', True, state(k, fine), 0.0)
        if k % 10 == 0:
            progress.written('/clock', False, cdr(k * PERIOD), 0.0)
    assert progress.value(1.0) == 12 * PERIOD
    assert progress.value(6.0) == 20 * PERIOD           # silent for 5 s: its publisher left
    progress.written('/clock', False, cdr(20 * PERIOD), 6.0)          # a re-send
    for k in range(21, 32):
        progress.written('/joint_states', True, state(k), 6.0)
        progress.written('/servo_commands', True, state(k, coarse), 6.0)
    assert progress.value(6.0) == 29 * PERIOD           # /clock at 20 is complete up to 29
    progress.written('/clock', False, cdr(30 * PERIOD), 6.0)
    assert progress.value(6.0) == 31 * PERIOD
    progress.written('/joint_states', True, state(0), 6.0)           # hw_sim started over
    assert progress.value(6.0) == 0


def test_recording_reports_loss_and_writes_it_into_custom_data(tmp_path):
    rec = recorder.Recording(tmp_path / 'bag', {'k': 'v'}, PERIOD)
    rec.add_topic('/joint_states', 'sensor_msgs/msg/JointState', [])
    rec.add_topic('/clock', 'rosgraph_msgs/msg/Clock', [])
    sent = []
    for k in range(25):
        if k not in (7, 8, 9) and rec.write('/joint_states', state(k), k, 0.0):
            sent.append(rec.progress.take(0.0))             # as the node does when it is due
    assert sent == [12 * PERIOD, 22 * PERIOD]           # the 10th and 20th state written
    for k in (0, 10, 30):
        assert rec.write('/clock', cdr(k * PERIOD), k, 0.0) is False
    rec.close()
    report = rec.report()
    assert '  /joint_states (sensor_msgs/msg/JointState): 22' in report
    assert 'lost (skipped stamps): /joint_states 3, /clock 1' in report
    with Bag(tmp_path / 'bag') as bag:
        assert bag.custom_data == {'k': 'v', 'machine_ctrl.namespace': '', 'machine_ctrl.lost/joint_states': '3',
                                   'machine_ctrl.stamps_back/joint_states': '0',
                                   'machine_ctrl.lost/clock': '1', 'machine_ctrl.stamps_back/clock': '0'}


def test_recording_without_a_machine_says_loss_is_not_checked(tmp_path):
    rec = recorder.Recording(tmp_path / 'bag')
    rec.add_topic('/joint_states', 'sensor_msgs/msg/JointState', [])
    rec.write('/joint_states', state(0), 0, 0.0)
    rec.write('/joint_states', state(5), 1, 0.0)
    rec.close()
    assert 'lost: not checked (no machine given' in rec.report()
    with Bag(tmp_path / 'bag') as bag:
        assert bag.custom_data == {'machine_ctrl.namespace': ''}


def test_progress_topic_is_not_recorded_unless_named():
    progress = contract.RECORDER_PROGRESS.name
    available = {'/joint_states': ['sensor_msgs/msg/JointState'], progress: ['builtin_interfaces/msg/Time']}
    assert set(recorder.to_subscribe(available, None, recorder.default_excluded(), {})) == {'/joint_states'}
    assert set(recorder.to_subscribe(available, {progress: None}, recorder.default_excluded(), {})) == {progress}


def test_a_recorder_in_a_namespace_records_its_own_graph_only():
    available = {'/mill1/joint_states': ['sensor_msgs/msg/JointState'],
                 '/mill2/joint_states': ['sensor_msgs/msg/JointState'],
                 '/mill1/recorder/progress': ['builtin_interfaces/msg/Time'],
                 '/rosout': ['rcl_interfaces/msg/Log']}
    chosen = recorder.to_subscribe(available, None, recorder.default_excluded('/mill1'), {}, '/mill1')
    assert set(chosen) == {'/mill1/joint_states'}
    assert recorder.parse_topic('joint_states', 'mill1') == ('/mill1/joint_states', None)
    assert recorder.parse_topic('/tf', 'mill1') == ('/tf', None)


def test_a_namespaced_recording_keeps_its_namespace_and_checks_its_own_streams(tmp_path):
    rec = recorder.Recording(tmp_path / 'bag', {}, PERIOD, namespace='mill1')
    rec.add_topic('/mill1/joint_states', 'sensor_msgs/msg/JointState', [])
    for k in (0, 1, 3):
        rec.write('/mill1/joint_states', state(k), k, 0.0)
    rec.close()
    with Bag(tmp_path / 'bag') as bag:
        assert bag.custom_data['machine_ctrl.namespace'] == '/mill1'
        assert bag.custom_data['machine_ctrl.lost/mill1/joint_states'] == '1'


def test_session_facts_go_into_custom_data_and_come_back(tmp_path):
    """KEY=VALUE facts of the recorded graph: machine_ctrl.session.KEY in the bag, read back
    by session_of; a fact that is not KEY=VALUE is refused naming it."""
    data = recorder.session_data(['mode=paced', 'real_time_factor=0.2', 'belief_1=/tmp/a=b.yaml'])
    assert data == {'machine_ctrl.session.mode': 'paced', 'machine_ctrl.session.real_time_factor': '0.2',
                    'machine_ctrl.session.belief_1': '/tmp/a=b.yaml'}
    recording = recorder.Recording(tmp_path / 'bag', data)
    recording.close()
    with Bag(tmp_path / 'bag') as bag:
        assert recorder.session_of(bag.custom_data) == {'mode': 'paced', 'real_time_factor': '0.2',
                                                        'belief_1': '/tmp/a=b.yaml'}
    for bad in ('mode', '=paced', '1mode=x', 'a b=c'):
        with pytest.raises(ValueError, match='is not KEY=VALUE'):
            recorder.session_data([bad])
