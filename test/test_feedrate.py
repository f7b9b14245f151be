"""Feed optimization on the grid, against closed forms and Ruckig's time optimum."""
import numpy as np
import pytest
from ruckig import InputParameter, Ruckig, Trajectory

from trajectory.feedrate import FeedLimits, accelerations, jerks, optimize_feed, refine_feed

V, A, J = 0.15, 5.0, 100.0


def circle(radius, n, axes=2):
    s = np.linspace(0.0, 2 * np.pi * radius, n)
    th = s / radius
    derivatives = [np.column_stack((-np.sin(th), np.cos(th))),
                   np.column_stack((-np.cos(th), -np.sin(th))) / radius,
                   np.column_stack((np.sin(th), -np.cos(th))) / radius**2]
    return s, derivatives


def limits(axes, feed=1.0):
    return FeedLimits(np.full(axes, V), np.full(axes, A), np.full(axes, J), feed)


def test_circle_profile_keeps_every_limit_on_the_grid_and_cruises_at_the_jerk_bound():
    radius = 4e-3
    s, (dq, ddq, dddq) = circle(radius, 1001)
    profile = optimize_feed(s, dq, ddq, dddq, limits(2))
    ds = s[1] - s[0]
    assert profile.b[0] == profile.b[-1] == 0.0
    assert (np.abs(dq) * profile.feed[:, None] <= V * (1 + 1e-9)).all()
    assert (np.abs(accelerations(profile.b, dq, ddq, ds)) <= A * (1 + 1e-6)).all()
    assert (np.abs(jerks(profile.b, dq, ddq, dddq, ds)) <= J * (1 + 1e-6)).all()
    # steady circular motion: axis jerk amplitude v^3/R^2 -> v = (J R^2)^(1/3), the binding limit
    cruise = (J * radius**2) ** (1 / 3)
    assert profile.feed[len(s) // 2] == pytest.approx(cruise, rel=0.02)


def test_process_feed_limit_caps_the_feed():
    s, (dq, ddq, dddq) = circle(30e-3, 801)
    profile = optimize_feed(s, dq, ddq, dddq, limits(2, feed=0.01))
    assert profile.feed.max() <= 0.01 * (1 + 1e-9)
    assert profile.feed[len(s) // 2] == pytest.approx(0.01, rel=1e-6)


@pytest.mark.parametrize('length', [0.02, 0.002])
def test_straight_line_approaches_the_time_optimum_as_the_grid_refines(length):
    inp = InputParameter(1)
    inp.current_position, inp.target_position = [0.0], [length]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [V], [A], [J]
    optimum = Trajectory(1)
    Ruckig(1).calculate(inp, optimum)
    ratios = []
    for n in (401, 1601):
        s = np.linspace(0.0, length, n)
        one, zero = np.ones((n, 1)), np.zeros((n, 1))
        ratios.append(optimize_feed(s, one, zero, zero, limits(1)).duration() / optimum.duration)
    assert 0.93 < ratios[0] < ratios[1] < 1.01


@pytest.mark.parametrize('grid, feed, message', [
    (np.r_[0.0, 0.1, 0.3, 0.4, 0.5], 1.0, 'uniformly spaced'),
    (np.linspace(0, 1, 4), 1.0, '>= 5'),
    (np.linspace(0, 1, 10), 0.0, 'feed limit must be > 0'),
])
def test_bad_input_is_refused(grid, feed, message):
    n = len(grid)
    with pytest.raises(ValueError, match=message):
        optimize_feed(grid, np.ones((n, 1)), np.zeros((n, 1)), np.zeros((n, 1)), limits(1, feed))


def test_refine_feed_keeps_the_scaled_limits_and_holds_the_nodes_outside_its_window():
    radius = 4e-3
    s, (dq, ddq, dddq) = circle(radius, 1001)
    profile = optimize_feed(s, dq, ddq, dddq, limits(2))
    scales = np.ones((1001, 3))
    scales[498:503, 2] = 0.9                   # the jerk limit lowered around the middle
    refined = refine_feed(s, profile.b, dq, ddq, dddq, limits(2), scales, [498, 502], 64)
    ds = s[1] - s[0]
    assert (np.abs(jerks(refined.b, dq, ddq, dddq, ds)) <= J * scales[1:-1, 2:] * (1 + 1e-6)).all()
    assert (np.abs(accelerations(refined.b, dq, ddq, ds)) <= A * (1 + 1e-6)).all()
    assert np.all(refined.b[498:503] < profile.b[498:503])
    # held outside the window, up to the uniform factor of the final exact-jerk check
    outside = np.ones(1001, bool)
    outside[[0, -1]] = outside[498 - 64:502 + 65] = False
    held = refined.b[outside] / profile.b[outside]
    assert 0.998 <= held.min() and np.ptp(held) <= 1e-12
    # a window too narrow for the dip within the jerk rows (here up to 32 nodes) is
    # infeasible: it doubles, 1 -> 64, to the same LP
    narrow = refine_feed(s, profile.b, dq, ddq, dddq, limits(2), scales, [498, 502], 1)
    assert np.array_equal(narrow.b, refined.b)


def test_refine_feed_refuses_scales_outside_0_1():
    s, (dq, ddq, dddq) = circle(4e-3, 11)
    with pytest.raises(ValueError, match='limit scales'):
        refine_feed(s, np.zeros(11), dq, ddq, dddq, limits(2), np.full((11, 3), 1.5), [5], 2)


def test_refine_feed_meets_lowered_velocity_and_acceleration_limits_and_rests_at_both_ends():
    s, (dq, ddq, dddq) = circle(4e-3, 1001)
    profile = optimize_feed(s, dq, ddq, dddq, limits(2))
    scales = np.ones((1001, 3))
    scales[200:260, 0] = 0.5                   # velocity halved over 60 nodes
    scales[600:640, 1] = 0.6                   # acceleration to 60 %
    refined = refine_feed(s, profile.b, dq, ddq, dddq, limits(2), scales, [*range(200, 260), *range(600, 640)], 32)
    ds = s[1] - s[0]
    speed = np.abs(dq) * np.sqrt(refined.b)[:, None]
    assert (speed <= V * scales[:, :1] * (1 + 1e-9)).all() and speed[200:260].max() > 0.4 * V
    assert (np.abs(accelerations(refined.b, dq, ddq, ds)) <= A * scales[1:-1, 1:2] * (1 + 1e-6)).all()
    assert (np.abs(jerks(refined.b, dq, ddq, dddq, ds)) <= J * (1 + 1e-6)).all()
    assert refined.b[0] == refined.b[-1] == 0.0 and (refined.b >= 0.0).all()
