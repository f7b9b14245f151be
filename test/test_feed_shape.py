"""The time law's feed profile between its nodes (trajectory/feed_shape.py): the uniform cubic
B-spline, the profile's control points, the feed bound's headroom."""
import numpy as np
import pytest

from trajectory.feed_shape import feed_headroom, profile_spline, rest_shape


def test_time_law_spline_has_the_lp_differences_at_the_nodes():
    from trajectory.feed_shape import control_point_spline
    rng = np.random.default_rng(5)
    d = np.linspace(0.0, 2e-3, 21)
    h = d[1] - d[0]
    c = rng.random(21)
    spline = control_point_spline(d, c)
    inner = slice(1, -1)
    assert np.allclose(spline(d[inner], 2), (c[:-2] - 2 * c[1:-1] + c[2:]) / h**2, rtol=1e-9)
    assert np.allclose(spline(d[inner], 1), (c[2:] - c[:-2]) / (2 * h), rtol=1e-9)
    assert spline(d[0]) == pytest.approx(c[0]) and spline(d[-1]) == pytest.approx(c[-1])
    assert spline(np.linspace(0.0, 2e-3, 401)).min() >= 0.0        # control points >= 0


def exact_uniform_cubic(length, coefficients, x) -> float:
    """A cubic B-spline with knots k length/spans (k = -3 ... spans + 3, exactly uniform) at
    x, by de Boor's algorithm in rational arithmetic."""
    from fractions import Fraction
    spans = len(coefficients) - 3
    h = Fraction(length) / spans
    knots = [k * h for k in range(-3, spans + 4)]
    c = [Fraction(v) for v in coefficients]
    x = Fraction(x)
    i = min(max(int(x / h), 0), spans - 1) + 3              # knots[i] <= x < knots[i + 1]
    d = [c[i - 3 + j] for j in range(4)]
    for r in range(1, 4):
        for j in range(3, r - 1, -1):
            a = (x - knots[j + i - 3]) / (knots[j + 1 + i - r] - knots[j + i - 3])
            d[j] = (1 - a) * d[j - 1] + a * d[j]
    return float(d[3])


def test_the_uniform_cubic_is_the_exact_b_spline_and_scipys_within_rounding():
    from scipy.interpolate import BSpline

    from trajectory.feed_shape import UniformCubic
    rng = np.random.default_rng(8)
    length, spans = 0.033, 999
    coefficients = rng.random(spans + 3)
    mine = UniformCubic(length, coefficients)
    x = np.concatenate((rng.uniform(0.0, length, 300), [0.0, length, length / 2]))
    exact = np.array([exact_uniform_cubic(length, coefficients, v) for v in x])
    # the float h = length / spans is rounded (1e-16): at span k ~ 1000 the parameter within
    # the span is off by ~k 1e-16, and the value (control points ~1) by as much
    np.testing.assert_allclose(mine(x), exact, rtol=0, atol=1e-13)
    # scipy's knots h k (h = length / spans) are rounded, ~1e-13 of a span at k ~ 1000
    h = length / spans
    reference = BSpline(h * np.arange(-3, spans + 4), coefficients, 3)
    x = np.concatenate((rng.uniform(0.0, length, 20_000), h * np.arange(spans + 1)))
    for nu in (0, 1, 2):
        want = reference(x, nu)
        assert np.abs(mine(x, nu) - want).max() <= 1e-12 * np.abs(want).max()
    with pytest.raises(ValueError, match='derivative order'):
        mine(x, 3)


def test_the_headroom_keeps_the_time_laws_feed_within_f_squared_and_reaches_it():
    """b = F^2 times the headroom at every node (1 mm/s, 25 mm, 1000 nodes): the time law's b(s)
    (E times its B-spline, evaluated by TimeLaw.feed) between the nodes, on a grid 200x
    finer, never over F^2 and at it within 1e-4 somewhere. With b = F^2 at every node it
    rises 22 % over (the rest ends), which this headroom takes away."""
    from trajectory.sampling import TimeLaw
    s = np.linspace(0.0, 0.025, 1000)
    f2 = 1e-6
    x = np.linspace(0.0, 0.025, 200 * 999 + 1)
    at_nodes = TimeLaw.from_profile(s, f2 * np.r_[0.0, np.ones(998), 0.0])
    assert np.max(at_nodes.feed(x)[0] ** 2) / f2 == pytest.approx(1.217, abs=1e-3)
    law = TimeLaw.from_profile(s, f2 * feed_headroom(s))
    b = law.feed(x)[0] ** 2
    assert b.max() <= f2 * (1 + 1e-9) and b.max() >= f2 * (1 - 1e-4)
    middle = (x > 0.006) & (x < 0.019)                 # a quarter in from either end: F itself
    assert b[middle].min() >= f2 * (1 - 1e-6)


def test_the_headroom_is_one_over_the_largest_rise_its_control_point_weighs_on():
    """By hand on a short grid: the profile b = 1's b(s) on each interval (its rise r), and a
    node's factor 1 / the largest r of the intervals j-2 .. j+1; the ends 0."""
    s = np.linspace(0.0, 1e-3, 9)
    d = s - s[0]
    spline = profile_spline(d, np.ones(9))
    x = np.linspace(0.0, 1e-3, 8 * 100_000 + 1)
    r = rest_shape(x, 1e-3) * spline(x)
    rise = [r[k * 100_000:(k + 1) * 100_000 + 1].max() for k in range(8)]
    want = [0.0] + [1.0 / max(rise[max(j - 2, 0):j + 2]) for j in range(1, 8)] + [0.0]
    np.testing.assert_allclose(feed_headroom(s), want, rtol=1e-8, atol=0)
    assert np.all(feed_headroom(s)[1:-1] < 1.0)      # every node of so short a path bends
