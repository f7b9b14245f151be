"""The trajectory node's reference stream (trajectory/stream.py): hold, play, feed
override as a time warp (exact rows at 100 %, on the path and within the limits while
ramping), feed hold / resume / stop, abort; and the joint-goal waypoint moves."""
import math

import numpy as np
import pytest
from limit_checks import assert_within_limits
from scipy.optimize import minimize_scalar

from machine_ctrl.model.kinematics import Kinematics
from trajectory import toolpath
from trajectory.moves import AxisState, move_to, smooth_stop, through_waypoints
from trajectory.planner import plan
from trajectory.ramp import SMOOTHSTEP_PEAK_CURVATURE, SMOOTHSTEP_PEAK_RATE, smoothstep
from trajectory.stream import ReferenceStream, TooLate


def limits(machine):
    return [a.limits for a in machine.axes]


def stream_of(machine, position, first=0):
    return ReferenceStream(machine.axis_names, machine.control_period, position, first)


def play(stream, steps, chunk=500):
    """Hand out `steps` rows; (positions, velocities) as arrays."""
    first, p, v, _ = stream.take(steps)
    return np.array(p), np.array(v)


@pytest.fixture(scope='module')
def arc_plan(micromill):
    """A planned 3 mm half circle at 10 mm/s (tool tips around the home tip)."""
    th = np.linspace(0.0, math.pi, 24)
    p = np.column_stack([1e-3 * (np.cos(th) - 1), 0.002 + 1e-3 * np.sin(th), np.full_like(th, 0.010)])
    return plan(toolpath.from_arrays(p, np.tile([0.0, 0.0, 1.0], (24, 1))), micromill, 0.01).unwrap()


def test_smoothstep_ends_flat():
    assert smoothstep(0.0) == (0.0, 0.0, 0.0) and smoothstep(1.0) == (1.0, 0.0, 0.0)
    u = np.linspace(0, 1, 1001)
    s = np.array([smoothstep(x)[0] for x in u])
    assert np.all(np.diff(s) >= 0)


def test_smoothstep_is_the_quintic_on_floats_and_arrays_alike():
    u = np.linspace(-0.5, 1.5, 2001)
    c = np.clip(u, 0.0, 1.0)
    expected = (6 * c**5 - 15 * c**4 + 10 * c**3, 30 * c**4 - 60 * c**3 + 30 * c**2,
                120 * c**3 - 180 * c**2 + 60 * c)
    on_array = smoothstep(u)
    on_floats = np.array([smoothstep(float(x)) for x in u]).T
    for k in range(3):
        np.testing.assert_allclose(on_array[k], expected[k], rtol=0, atol=1e-13)
        np.testing.assert_allclose(on_floats[k], expected[k], rtol=0, atol=1e-13)
    inside = (u > 0) & (u < 1)
    assert np.abs(on_array[1][inside]).max() == pytest.approx(15 / 8, rel=1e-6)
    assert np.abs(on_array[2][inside]).max() == pytest.approx(10 / math.sqrt(3), rel=1e-5)
    assert SMOOTHSTEP_PEAK_RATE == 15 / 8 and SMOOTHSTEP_PEAK_CURVATURE == pytest.approx(5.773502691896258)


def test_full_feed_plays_the_planned_rows_exactly_then_holds(micromill):
    here = [1e-3] + [0.0] * 8
    stream = stream_of(micromill, here, first=7)
    first, p, v, a = stream.take(5)
    assert first == 7 and all(row == tuple(here) for row in p) and not np.any(v) and not np.any(a)
    move = move_to(micromill, [2e-3] + [0.0] * 8, AxisState.at_rest(here))
    motion = stream.start(move, 'move', limits(micromill))
    assert motion.start == 12
    first, p, v, a = stream.take(len(move) + 3)
    np.testing.assert_array_equal(np.array(p[:len(move)]), move.position)
    np.testing.assert_array_equal(np.array(v[:len(move) - 1]), move.velocity[:-1])
    np.testing.assert_array_equal(np.array(a[:len(move) - 1]), move.acceleration[:-1])
    assert p[-1] == tuple(move.position[-1]) and not np.any(v[-1])
    assert not stream.busy(first + len(p)) and stream.progress(first + len(p)) == 1.0


def test_a_motion_that_would_jump_or_overlap_is_refused(micromill):
    stream = stream_of(micromill, [0.0] * 9)
    elsewhere = move_to(micromill, [2e-3] + [0.0] * 8, AxisState.at_rest([1e-3] + [0.0] * 8))
    with pytest.raises(ValueError, match='away from the stream position'):
        stream.start(elsewhere, 'jump', limits(micromill))
    stream.start(move_to(micromill, [2e-3] + [0.0] * 8), 'first', limits(micromill))
    with pytest.raises(ValueError, match='under way'):
        stream.start(move_to(micromill, [0.0] * 9), 'second', limits(micromill))


def distance_to_path(result, kin, q):
    """Tool-tip distance (m) of configuration q from the planned path R(s)."""
    tip, _ = kin.forward(q)
    s_grid = result.sampling.s
    p_grid, _ = result.path.evaluate(s_grid)
    j = int(np.argmin(np.linalg.norm(p_grid - tip, axis=1)))
    lo, hi = s_grid[max(j - 1, 0)], s_grid[min(j + 1, len(s_grid) - 1)]
    best = minimize_scalar(lambda s: np.linalg.norm(result.path.evaluate(np.array([s]))[0][0] - tip),
                           bounds=(lo, hi), method='bounded', options={'xatol': 1e-15})
    return best.fun


def test_feed_hold_stops_on_the_path_within_the_limits_and_resume_finishes(micromill, arc_plan):
    ref = arc_plan.reference
    stream = stream_of(micromill, ref.position[0])
    stream.start(ref, 'arc', limits(micromill))
    before, _ = play(stream, len(ref) // 3)
    begin = stream.set_override(0.0, at=len(ref) // 4)           # rows from there are re-sent
    assert begin == len(ref) // 4 and stream.next_step == begin + 1
    held, v_held = play(stream, len(ref))
    positions = np.vstack([before[:begin + 1], held])
    assert_within_limits(micromill, positions)
    assert not np.any(v_held[-10:]) and stream.busy(len(positions))        # at rest, program kept
    kin = Kinematics.from_config(micromill)
    assert max(distance_to_path(arc_plan, kin, q) for q in positions[begin::97]) < 1e-9
    stopped_at = stream.progress(len(positions))
    assert 0.25 < stopped_at < 0.9

    stream.set_override(1.0, at=len(positions))
    rest, _ = play(stream, 2 * len(ref))
    positions = np.vstack([positions, rest])
    assert_within_limits(micromill, positions)
    np.testing.assert_array_equal(positions[-1], ref.position[-1])
    assert not stream.busy(len(positions))


def test_half_feed_takes_twice_as_long_and_stop_ends_the_motion(micromill, arc_plan):
    ref = arc_plan.reference
    stream = stream_of(micromill, ref.position[0])
    stream.start(ref, 'arc', limits(micromill), override=0.5)
    half, _ = play(stream, 3 * len(ref))
    assert_within_limits(micromill, half)
    end = stream.motion.end
    assert abs(end - 2 * (len(ref) - 1)) <= 2                    # tau advances by 0.5 per step

    stream = stream_of(micromill, ref.position[0])
    stream.start(ref, 'arc', limits(micromill))
    first, _ = play(stream, len(ref) // 2)
    stream.set_override(0.0, at=len(ref) // 3, stop=True)
    rest, v = play(stream, len(ref))
    assert_within_limits(micromill, np.vstack([first[:len(ref) // 3 + 1], rest]))
    assert not stream.busy(stream.next_step) and not np.any(v[-1])
    with pytest.raises(ValueError, match='no motion under way'):
        stream.set_override(1.0, at=stream.next_step)


def test_override_outside_a_fraction_is_refused_and_abort_holds(micromill):
    stream = stream_of(micromill, [0.0] * 9)
    move = move_to(micromill, [40e-3] + [0.0] * 8)
    stream.start(move, 'long', limits(micromill))
    with pytest.raises(ValueError, match='within'):
        stream.set_override(1.5, at=10)
    positions, _ = play(stream, len(move) // 2)
    stream.abort(100)
    assert stream.next_step == 100 and not stream.busy(100)
    first, p, v, _ = stream.take(3)
    assert first == 100 and p[0] == tuple(positions[100]) and not np.any(v)


def test_a_cut_plays_a_stop_from_the_state_the_stream_gives_there(micromill):
    """A point-to-point move at the limits is stopped by a cut: the stop planned from the
    stream's state at the cut step, played from there, then held; within the limits."""
    stream = stream_of(micromill, [0.0] * 9)
    move = move_to(micromill, [40e-3] + [0.0] * 8)
    stream.start(move, 'long', limits(micromill))
    played, _ = play(stream, len(move) // 2)
    at = len(move) // 4
    p, v, a = stream.state(at)
    np.testing.assert_array_equal(p, move.position[at])
    np.testing.assert_array_equal(v, move.velocity[at])
    np.testing.assert_array_equal(a, move.acceleration[at])
    tail = smooth_stop(micromill, AxisState(tuple(p), tuple(v), tuple(a)))
    assert stream.cut(at, tail) == at and stream.next_step == at + 1       # rows after the cut re-sent
    rest, v_rest = play(stream, len(move))
    positions = np.vstack([played[:at + 1], rest])
    assert_within_limits(micromill, positions)
    np.testing.assert_array_equal(positions[at + len(tail) - 1:], np.tile(tail.position[-1], (len(positions) - at - len(tail) + 1, 1)))
    assert not np.any(v_rest[len(tail) - 1:]) and not stream.busy(at + len(tail) - 1)
    assert 0.0 < stream.progress(at + len(tail)) < 0.5 and stream.override(at + len(tail)) == 0.0
    assert positions[-1][0] < 40e-3 - 1e-3                           # stopped short of the goal
    with pytest.raises(ValueError, match='not streamed yet'):
        other = stream_of(micromill, [0.0] * 9)
        other.start(move, 'long', limits(micromill))
        other.state(10)


def test_a_ramp_to_0_that_cannot_end_before_the_motion_does_is_too_late(micromill):
    stream = stream_of(micromill, [0.0] * 9)
    move = move_to(micromill, [40e-3] + [0.0] * 8)
    stream.start(move, 'long', limits(micromill))
    play(stream, len(move) - 50)
    with pytest.raises(TooLate, match='too late: the motion reaches its end'):
        stream.set_override(0.0, at=len(move) - 100)
    assert stream.motion.ramp.k1 == 1.0                               # nothing changed
    rest, _ = play(stream, 100)
    np.testing.assert_array_equal(rest[49], move.position[-1])


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
