"""Ruckig point-to-point moves: exact goals, limits kept when sampled at the control
period, continuity from a moving start, smooth stop, refused goals."""
import math

import numpy as np
import pytest
from limit_checks import assert_reference_within_limits, assert_within_limits, rounding_error

from trajectory.axis_limits import unlimited_range
from trajectory.moves import AxisState, home, move_to, move_to_state, smooth_stop, through_waypoints, validate_goal

GOAL = [0.01, -0.02, 0.03, 5e-5, -4e-5, 2e-5, 0.001, -0.002, 1.0]


def test_rest_to_rest_move_reaches_the_goal_exactly(micromill):
    reference = move_to(micromill, GOAL)
    np.testing.assert_allclose(reference.position[0], micromill.home, atol=0)
    np.testing.assert_allclose(reference.position[-1], GOAL, rtol=0, atol=1e-12)
    np.testing.assert_allclose(reference.velocity[-1], 0.0, atol=1e-12)
    assert_within_limits(micromill, reference.position)
    # synchronized: every moving axis is still moving one step before the end
    moving = np.abs(np.array(GOAL) - micromill.home) > 0
    assert (np.abs(reference.velocity[-2][moving]) > 0).all()


def test_move_from_a_moving_state_is_continuous(micromill):
    first = move_to(micromill, GOAL)
    k = len(first) // 3
    start = AxisState(tuple(first.position[k]), tuple(first.velocity[k]), tuple(first.acceleration[k]))
    second = move_to(micromill, micromill.home, start)
    np.testing.assert_allclose(second.position[0], first.position[k], atol=1e-15)
    np.testing.assert_allclose(second.velocity[0], first.velocity[k], atol=1e-12)
    joined = np.vstack((first.position[:k], second.position))
    assert_within_limits(micromill, joined)


def test_smooth_stop_brings_every_axis_to_rest(micromill):
    first = move_to(micromill, GOAL)
    k = len(first) // 2
    start = AxisState(tuple(first.position[k]), tuple(first.velocity[k]), tuple(first.acceleration[k]))
    stop = smooth_stop(micromill, start)
    np.testing.assert_allclose(stop.velocity[-1], 0.0, atol=1e-12)
    np.testing.assert_allclose(stop.acceleration[-1], 0.0, atol=1e-9)
    assert len(stop) < len(first) - k                    # sooner than finishing the move
    assert_within_limits(micromill, stop.position)


def test_home_returns_to_home(micromill):
    reference = home(micromill, AxisState.at_rest(GOAL))
    np.testing.assert_allclose(reference.position[-1], micromill.home, atol=1e-12)


@pytest.mark.parametrize('goal, message', [
    (GOAL[:8], 'goal needs 9 positions'),
    (GOAL[:8] + [float('nan')], 'c_f at nan: NaN or inf is not a position'),
    ([0.06] + GOAL[1:], r'x_c at 0.06 m, outside its stroke \[-0.05, 0.05\] m by 10 mm'),
    (GOAL[:3] + [2e-4] + GOAL[4:], r'x_f at 0.0002 m, outside its stroke \[-0.0001, 0.0001\] m by 100 µm'),
    (GOAL[:7] + [-0.01] + GOAL[8:], r'b_f at -0.01 rad, outside its stroke \[-0.00872665, 0.00872665\] rad '
                                    r'by 1.27 mrad'),
    # c_f is unlimited: ulp(q) <= 0.001 x 2 pi rad/s x 100 µs = 6.3e-7 rad up to 2^31 rad
    (GOAL[:8] + [2.2e9], r'c_f at 2\.2e\+09 rad, beyond ±2\.14748e\+09 rad \(341782638 turns\), the range of '
                         r'its unlimited axis'),
])
def test_bad_goals_are_refused(micromill, goal, message):
    with pytest.raises(ValueError, match=message):
        move_to(micromill, goal)


def test_the_unlimited_range_is_where_float64_resolves_the_velocity_at_the_control_period(micromill, trt,
                                                                                         fts_lathe):
    # micromill c_f: 0.001 x 2 pi rad/s x 100 µs = 6.28e-7 rad lies in [ulp of [2^31, 2^32), ulp of [2^32, 2^33))
    c_f = micromill.axes[micromill.axis_names.index('c_f')]
    assert unlimited_range(c_f, micromill.control_period) == 2.0**31
    assert np.spacing(2.0**31) <= 6.28e-7 < np.spacing(2.0**32)
    # trt_5axis c: 0.001 x 6 rad/s x 1 ms = 6e-6 rad = between the ulps of [2^34, 2^35) and [2^35, 2^36)
    c = trt.axes[trt.axis_names.index('c')]
    assert unlimited_range(c, trt.control_period) == 2.0**34
    assert np.spacing(2.0**34) <= 6e-6 < np.spacing(2.0**35)
    # fts_lathe c: 0.001 x 125.66 rad/s x 5.01 µs = 6.30e-7 rad: 2^31 as well
    spindle = fts_lathe.axes[fts_lathe.axis_names.index('c')]
    assert unlimited_range(spindle, fts_lathe.control_period) == 2.0**31
    validate_goal(micromill, GOAL[:8] + [-2.0**31])          # the edge itself is accepted


def test_the_rounding_bound_holds_for_an_exactly_known_motion_far_from_zero():
    """A cubic q = q0 + j t³ / 6 has the third difference j T³ exactly; its float64 samples at
    q0 = 1e4 rad (computed in exact rationals, then rounded once) differ from it by no more
    than rounding_error(3, ..., ulps=1/2) (rounding alone), and come within a factor 4 of it."""
    from fractions import Fraction
    period, jerk, q0 = Fraction(5, 10**6), Fraction(2000), Fraction(10**4)
    exact = [q0 + jerk * (k * period) ** 3 / 6 for k in range(400)]
    rounded = np.array([float(q) for q in exact])
    third = np.diff(rounded, 3) / float(period) ** 3
    error = np.abs(third - float(jerk)).max()
    bound = rounding_error(3, 1e4 + 1.0, float(period), ulps=0.5)
    assert error <= bound
    assert error > bound / 4


def test_a_spindle_moves_to_any_angle_a_turn_away_and_back_home(fts_lathe):
    """fts_lathe's c at 5 µs: a quarter turn, then on to 20 rad (three turns) and home again,
    each within the limits as sampled (what a servo sees, with float64's rounding of the angle)."""
    names = fts_lathe.axis_names
    quarter = [math.pi / 2 if n == 'c' else 0.0 for n in names]
    far = [20.0 if n == 'c' else 0.0 for n in names]
    for start, goal in ((fts_lathe.home, quarter), (quarter, far), (far, fts_lathe.home)):
        reference = move_to(fts_lathe, goal, start=AxisState.at_rest(start))
        np.testing.assert_allclose(reference.position[-1], goal, rtol=0, atol=1e-12)
        assert_within_limits(fts_lathe, reference.position)
        assert_reference_within_limits(fts_lathe, reference)


def test_a_move_far_out_on_an_unlimited_axis_is_planned_relative_to_its_start(micromill):
    """c_f a turn on from 2^30 rad (inside its 2^31 rad range): Ruckig plans the distance to
    go, not the 1e9 rad (where it found no profile before), and the velocity from consecutive
    positions stays within 0.1 % of the limit with no allowance: what the range promises."""
    start = GOAL[:8] + [2.0**30]
    goal = GOAL[:8] + [2.0**30 + 2 * math.pi]
    reference = move_to(micromill, goal, start=AxisState.at_rest(start))
    column = reference.position[:, 8]
    assert column[0] == 2.0**30 and abs(column[-1] - goal[8]) <= np.spacing(2.0**30)
    velocity = np.abs(np.diff(column)).max() / micromill.control_period
    assert velocity <= 1.001 * micromill.axis('c_f').limits.velocity
    assert_reference_within_limits(micromill, reference)


def test_stop_that_cannot_end_inside_the_stroke_is_refused(micromill):
    near_end = list(micromill.home)
    near_end[0] = 0.0499
    velocity = [0.0] * 9
    velocity[0] = 0.15                                   # full speed towards the +50 mm end
    # jerk-limited stop from 0.15 m/s (a_max 5 m/s² not reached): 2 tau with j tau² = v,
    # tau = 38.7 ms, at the mean speed v/2: 5.81 mm further, 5.71 mm beyond the stroke end
    with pytest.raises(ValueError, match=r'x_c would reach 0.0557\d* m, outside its stroke \[-0.05, 0.05\] m '
                                         r'by 5.71 mm'):
        smooth_stop(micromill, AxisState(tuple(near_end), tuple(velocity), (0.0,) * 9))


# x_c's rest-to-rest time-optimal 1 mm (v 0.15 m/s, a 5 m/s², j 100 m/s³ not reached): four
# jerk phases of tau, 2 j tau³ = 1 mm: tau = 17.1 ms, 68.4 ms in all
EARLIEST = 4 * (1e-3 / (2 * 100.0)) ** (1 / 3)


@pytest.mark.parametrize('names, points, times, message', [
    (['x_c'], [[1e-3]], [1e-6], r'point 0: 1 mm in 1 µs on x_c needs 1000 m/s \(limit 150 mm/s\); '
                                r'earliest time_from_start 0.0684 s'),
    (['x_c'], [[1e-3]], [0.02], r'point 0: 1 mm in 20 ms on x_c needs more than its acceleration and jerk limits '
                                r'allow \(5 m/s², 100 m/s³\); earliest time_from_start 0.0684 s'),
    (['x_c', 'y_c'], [[0.0, 1e-3], [1e-3, 1e-3]], [0.5, 0.51],
     r'point 1: 1 mm in 10 ms on x_c needs more than its acceleration and jerk limits allow .*; '
     r'earliest time_from_start 0.5684 s'),                  # 0.5 s + the 68.4 ms of EARLIEST
    (['x_c'], [[1e-3]], [1e6], r'point 0: time_from_start 1e\+06 s is beyond the 104.858 s a joint goal may last '
                               r'\(1048576 control steps\)'),
    (['c_f'], [[1e10]], [0.0], r'point 0: c_f at 1e\+10 rad, beyond ±2\.14748e\+09 rad \(341782638 turns\)'),
    # 2000 rad at the 2 pi rad/s limit of c_f: > 318 s
    (['c_f'], [[2000.0]], [0.0], r'point 0: the joint goal would last at least 318\.31 s up to it, beyond the '
                                 r'104\.858 s'),
    (['c_f'], [[1e9]], [0.0], r'point 0: the joint goal would last at least 1\.59155e\+08 s up to it'),
    (['x_f'], [[5e-4]], [0.0], r'point 0: x_f at 0.0005 m, outside its stroke \[-0.0001, 0.0001\] m by 400 µm'),
    (['x_c'], [[0.0], [float('nan')]], [0.0, 0.0], 'point 1: x_c at nan: NaN or inf is not a position'),
])
def test_joint_goals_are_refused_naming_the_point_and_the_axis(micromill, names, points, times, message):
    with pytest.raises(ValueError, match=message):
        through_waypoints(micromill, [0.0] * 9, names, points, times)


def test_a_joint_goal_at_its_earliest_time_runs_and_arrives_then(micromill):
    assert EARLIEST == pytest.approx(0.068399, abs=1e-6)
    t = 0.0685                                           # the earliest, on the next 100 µs step
    reference = through_waypoints(micromill, [0.0] * 9, ['x_c'], [[1e-3]], [t])
    assert len(reference) - 1 == 685
    np.testing.assert_allclose(reference.position[-1, 0], 1e-3, atol=1e-12)
    with pytest.raises(ValueError, match='earliest time_from_start 0.0684 s'):
        through_waypoints(micromill, [0.0] * 9, ['x_c'], [[1e-3]], [0.0683])
    later = through_waypoints(micromill, [0.0] * 9, ['x_c'], [[1e-3], [2e-3]], [t, t + 0.1])
    assert len(later) - 1 == 685 + 1000                  # each point at its time


def test_a_move_ruckig_fails_to_solve_is_refused_naming_the_axis(fts_lathe):
    """Ruckig raises (RuckigError) where it finds no profile: here fts_lathe's w from 0.55 pm to
    a state under way 0.44 µm away (a cut's first row without a lead-in). The move is refused
    as any other, with the axis, not with Ruckig's dump of its input."""
    start = AxisState.at_rest((7.417749063051994, 0.0009940971428500261, 0.0, 5.528630581073707e-13))
    target = AxisState((7.417749063051994, 0.001, 0.0, -4.363647186335865e-07),
                       (12.56637061435917, -1e-05, 0.0, 0.0004548856632746526), (0.0, 0.0, 0.0, -0.01081372245328538))
    with pytest.raises(ValueError, match=r'^Ruckig cannot plan this move \(Ruckig found no profile for w in its step 1\)$'):
        move_to_state(fts_lathe, target, start, 0.98)


def test_amounts_in_reasons_read_in_three_digits_with_the_prefix_after_rounding():
    """A measured start 1 mm away is 0.99999... mm: its speed read '1e+03 m/s' (a ROS goal of
    1 mm in 1 µs, test_trajectory_node) where the offline goal read '1000 m/s'."""
    from trajectory.axis_limits import amount
    assert amount(999.99, 'm/s') == '1000 m/s' and amount(0.99999e-3, 'm') == '1 mm'
    assert (amount(0.0032, 'm'), amount(0.091, 'rad'), amount(4e-4, 'm')) == ('3.2 mm', '91 mrad', '400 µm')
