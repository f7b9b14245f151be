"""Ruckig point-to-point moves: exact goals, limits kept when sampled at the control
period, continuity from a moving start, smooth stop, refused goals."""
import numpy as np
import pytest
from limit_checks import assert_within_limits

from trajectory.moves import AxisState, home, move_to, smooth_stop

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
    (GOAL[:8] + [float('nan')], 'NaN or inf'),
    ([0.06] + GOAL[1:], 'for x_c is outside its stroke'),
    (GOAL[:3] + [2e-4] + GOAL[4:], 'for x_f is outside its stroke'),
])
def test_bad_goals_are_refused(micromill, goal, message):
    with pytest.raises(ValueError, match=message):
        move_to(micromill, goal)


def test_stop_that_cannot_end_inside_the_stroke_is_refused(micromill):
    near_end = list(micromill.home)
    near_end[0] = 0.0499
    velocity = [0.0] * 9
    velocity[0] = 0.15                                   # full speed towards the +50 mm end
    with pytest.raises(ValueError, match='x_c would reach'):
        smooth_stop(micromill, AxisState(tuple(near_end), tuple(velocity), (0.0,) * 9))
