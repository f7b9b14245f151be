"""Feed optimization on the grid, against closed forms and Ruckig's time optimum."""
import numpy as np
import pytest
from ruckig import InputParameter, Ruckig, Trajectory

from trajectory.feedrate import FeedLimits, optimize_feed, refine_feed

V, A, J = 0.15, 5.0, 100.0
# The optimizer's promise holds at the grid nodes (trajectory/feedrate.py), so the limits are
# checked there, in time (timed_at_nodes), not with the optimizer's chain-rule formulas: the
# central differences of its time derivatives err by O(h^2) (h^2/4 of the fifth derivative for
# the jerk): with h = 1 % of the time across a grid step, the scale on which the motion changes,
# ~(0.01)^2 = 1e-4 of the jerk up to a factor of order one, measured 6e-6 (a quarter of that
# when h halves); the rounding of the displacements (~eps sdot h / h^3) ~1e-7 of it.
FD_TOLERANCE = 1e-4


def circle(radius, n, axes=2):
    s = np.linspace(0.0, 2 * np.pi * radius, n)
    th = s / radius
    derivatives = [np.column_stack((-np.sin(th), np.cos(th))),
                   np.column_stack((-np.cos(th), -np.sin(th))) / radius,
                   np.column_stack((np.sin(th), -np.cos(th))) / radius**2]
    return s, derivatives


def arc_displacement(radius):
    """q(s + x) - q(s) on the circle of circle() (q = radius (cos, sin) of s / radius), in the
    product form that keeps digits for x << s."""
    def displacement(s, x):
        th, half = s / radius, x / (2 * radius)
        return 2 * radius * np.sin(half)[:, None] * np.column_stack((-np.sin(th + half), np.cos(th + half)))
    return displacement


def timed_at_nodes(s, b, displacement, fraction=0.01, substeps=50):
    """Axis velocity, acceleration and jerk at the interior nodes of the profile b = sdot^2,
    by central differences in time of positions: about node n the path is travelled at
    ds/dt = sqrt(b(s)), b the parabola through b[n-1], b[n], b[n+1] (whose slope and
    curvature at s[n] are the grid's central differences, the optimizer's model), integrated
    by RK4 to t = +-h, +-2h, h = `fraction` of the time across a grid step there, and the
    axis positions displacement(s[n], s(t) - s[n]) differenced."""
    ds = s[1] - s[0]
    b0, b1, b2 = b[:-2], b[1:-1], b[2:]
    assert (b1 > 0).all()
    slope, curve = (b2 - b0) / (2 * ds), (b2 - 2 * b1 + b0) / ds ** 2
    h = fraction * ds / np.sqrt(b1)

    def rate(x):
        return np.sqrt(np.maximum(b1 + slope * x + 0.5 * curve * x * x, 0.0))
    at = {0: np.zeros_like(b1)}
    for sign in (1, -1):
        x, dt = np.zeros_like(b1), sign * h / substeps
        for step in range(1, 2 * substeps + 1):
            k1 = rate(x)
            k2 = rate(x + dt / 2 * k1)
            k3 = rate(x + dt / 2 * k2)
            x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + rate(x + dt * k3))
            if step % substeps == 0:
                at[sign * step // substeps] = x
    p = [displacement(s[1:-1], at[k]) for k in (-2, -1, 0, 1, 2)]
    h = h[:, None]
    return (p[3] - p[1]) / (2 * h), (p[3] + p[1]) / h ** 2, (p[4] - 2 * p[3] + 2 * p[1] - p[0]) / (2 * h ** 3)


def limits(axes, feed=1.0):
    return FeedLimits(np.full(axes, V), np.full(axes, A), np.full(axes, J), feed)


def test_circle_profile_keeps_every_limit_on_the_grid_and_cruises_at_the_jerk_bound():
    radius = 4e-3
    s, (dq, ddq, dddq) = circle(radius, 1001)
    profile = optimize_feed(s, dq, ddq, dddq, limits(2))
    assert profile.b[0] == profile.b[-1] == 0.0
    v, a, j = timed_at_nodes(s, profile.b, arc_displacement(radius))
    assert np.abs(v).max() <= V * (1 + FD_TOLERANCE)
    assert np.abs(a).max() <= A * (1 + FD_TOLERANCE)
    assert np.abs(j).max() <= J * (1 + FD_TOLERANCE)
    # steady circular motion: axis jerk amplitude v^3/R^2 -> v = (J R^2)^(1/3), the binding limit
    cruise = (J * radius**2) ** (1 / 3)
    assert profile.feed[len(s) // 2] == pytest.approx(cruise, rel=0.02)
    assert np.abs(j).max() >= J * 0.999           # the jerk limit is the one reached


def test_process_feed_limit_caps_the_feed():
    s, (dq, ddq, dddq) = circle(30e-3, 801)
    profile = optimize_feed(s, dq, ddq, dddq, limits(2, feed=0.01))
    velocity = timed_at_nodes(s, profile.b, arc_displacement(30e-3))[0]
    speed = np.linalg.norm(velocity, axis=1)                # the tool's: the two axes span its plane
    assert speed.max() <= 0.01 * (1 + FD_TOLERANCE)
    assert speed[len(s) // 2] == pytest.approx(0.01, rel=FD_TOLERANCE)


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
    _, a, j = timed_at_nodes(s, refined.b, arc_displacement(radius))
    assert (np.abs(j) <= J * scales[1:-1, 2:] * (1 + FD_TOLERANCE)).all()
    assert (np.abs(a) <= A * (1 + FD_TOLERANCE)).all()
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
    v, a, j = timed_at_nodes(s, refined.b, arc_displacement(4e-3))
    speed = np.abs(v)
    assert (speed <= V * scales[1:-1, :1] * (1 + FD_TOLERANCE)).all() and speed[199:259].max() > 0.4 * V
    assert (np.abs(a) <= A * scales[1:-1, 1:2] * (1 + FD_TOLERANCE)).all()
    assert (np.abs(j) <= J * (1 + FD_TOLERANCE)).all()
    assert refined.b[0] == refined.b[-1] == 0.0 and (refined.b >= 0.0).all()
