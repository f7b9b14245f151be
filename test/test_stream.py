"""The trajectory node's reference stream (trajectory/stream.py) and the joint-goal
waypoint moves (trajectory/moves.py): hold, play, re-send after an interrupt, refusals."""
import numpy as np
import pytest

from trajectory.moves import AxisState, move_to, smooth_stop, through_waypoints
from trajectory.stream import ReferenceStream


def stream_of(machine, position, first=0):
    return ReferenceStream(machine.axis_names, machine.control_period, position, first)


def test_stream_holds_plays_and_holds_the_end(micromill):
    here = [1e-3] + [0.0] * 8
    stream = stream_of(micromill, here, first=7)
    first, p, v, a = stream.take(5)
    assert first == 7 and all(row == tuple(here) for row in p) and not np.any(v) and not np.any(a)
    move = move_to(micromill, [2e-3] + [0.0] * 8, AxisState.at_rest(here))
    motion = stream.start(move, 'move')
    assert motion.start == 12 and motion.end == 12 + len(move) - 1
    first, p, _, _ = stream.take(len(move) + 3)
    np.testing.assert_array_equal(np.array(p[:len(move)]), move.position)
    assert p[-1] == tuple(move.position[-1])
    assert stream.progress(motion.start) == 0.0 and stream.progress(motion.end + 5) == 1.0


def test_stream_refuses_a_motion_that_would_jump_or_overlap(micromill):
    stream = stream_of(micromill, [0.0] * 9)
    elsewhere = move_to(micromill, [2e-3] + [0.0] * 8, AxisState.at_rest([1e-3] + [0.0] * 8))
    with pytest.raises(ValueError, match='away from the stream position'):
        stream.start(elsewhere, 'jump')
    stream.start(move_to(micromill, [2e-3] + [0.0] * 8), 'first')
    with pytest.raises(ValueError, match='under way'):
        stream.start(move_to(micromill, [0.0] * 9), 'second')


def test_interrupt_resends_from_its_step_without_a_jump(micromill):
    stream = stream_of(micromill, [0.0] * 9)
    move = move_to(micromill, [40e-3] + [0.0] * 8)
    stream.start(move, 'long')
    stream.take(len(move))                                 # everything handed out
    at = len(move) // 3
    stop = smooth_stop(micromill, stream.state(at))
    stream.interrupt(at, stop, 'hold')
    first, p, _, _ = stream.take(len(stop) + 2)
    assert first == at
    joined = np.vstack([move.position[:at], np.array(p)])
    assert np.abs(np.diff(joined[:, 0])).max() <= 1.001 * micromill.axes[0].limits.velocity * micromill.control_period
    assert 0 < joined[-1, 0] < 40e-3 and not stream.busy(first + len(p))


def test_waypoints_keep_unnamed_axes_and_stop_at_each_point(micromill):
    start = [1e-3, 2e-3, 0, 0, 0, 0, 0, 0, 0]
    ref = through_waypoints(micromill, start, ['y_c', 'x_c'], [[3e-3, 0.0], [0.0, 1e-3]], [0.0, 0.0])
    assert ref.position[0].tolist() == start
    np.testing.assert_allclose(ref.position[-1], [1e-3, 0.0] + [0.0] * 7, atol=1e-12)
    at_first = np.flatnonzero(np.all(np.abs(ref.position[:, :2] - [0.0, 3e-3]) < 1e-12, axis=1))
    assert len(at_first) and np.abs(ref.velocity[at_first[0]]).max() < 1e-12      # at rest there


def test_timed_waypoints_arrive_no_earlier_than_asked(micromill):
    fast = through_waypoints(micromill, [0.0] * 9, ['x_c'], [[1e-3]], [0.0])
    slow = through_waypoints(micromill, [0.0] * 9, ['x_c'], [[1e-3]], [0.5])
    assert len(fast) < 0.5 / micromill.control_period <= len(slow) - 1


@pytest.mark.parametrize('names, points, times, reason', [
    (['x_c', 'w'], [[0.0, 0.0]], [0.0], 'unknown joints w'),
    (['x_c', 'x_c'], [[0.0, 0.0]], [0.0], 'duplicate'),
    ([], [[]], [0.0], 'names no joints'),
    (['x_c'], [[0.0, 1.0]], [0.0], '2 positions for 1 joints'),
    (['x_c'], [[float('inf')]], [0.0], 'NaN or inf'),
    (['y_c'], [[0.06]], [0.0], 'outside its stroke'),
    (['x_c'], [[0.0], [1e-3]], [0.3, 0.3], 'strictly increasing'),
    (['x_c'], [[0.0]], [float('nan')], 'NaN or inf'),
    (['x_c'], [], [], 'no points'),
])
def test_waypoints_refuse_bad_goals(micromill, names, points, times, reason):
    with pytest.raises(ValueError, match=reason):
        through_waypoints(micromill, [0.0] * 9, names, points, times)
