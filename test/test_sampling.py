"""Septic interpolation (Eqs. 3.39-3.40) and time sampling (Eq. 3.38) of a resolved path."""
import math

import numpy as np
import pytest

from trajectory import toolpath
from trajectory.feedrate import FeedLimits, optimize_feed
from trajectory.redundancy import resolve
from trajectory.sampling import LimitsExceeded, SepticInterpolant, sample
from trajectory.spline import ArcLengthPath


def test_septic_interpolant_reproduces_a_degree_7_polynomial_and_its_derivatives():
    poly = np.polynomial.Polynomial([0.3, -1.0, 2.0, 0.5, -4.0, 1.5, 0.7, -2.0])
    s = np.array([0.0, 0.13, 0.31, 0.5, 0.82, 1.0])
    data = [poly.deriv(k)(s)[:, None] for k in range(4)]
    interp = SepticInterpolant(s, *data)
    x = np.linspace(0.0, 1.0, 97)
    for k in range(4):
        assert np.allclose(interp.evaluate(x, k)[:, 0], poly.deriv(k)(x), rtol=0, atol=1e-10)


def test_septic_interpolant_rejects_non_increasing_nodes():
    q = np.zeros((3, 1))
    with pytest.raises(ValueError, match='increasing'):
        SepticInterpolant([0.0, 1.0, 1.0], q, q, q, q)


def sampled_quarter_helix(micromill, micromill_kin, feed):
    """The quarter helix resolved, its feed optimized at `feed` and sampled."""
    path = ArcLengthPath.fit(toolpath.helix(turns=0.25))
    res = resolve(path, micromill_kin, micromill)
    limits = FeedLimits.from_machine(micromill, feed)
    idx = np.arange(0, len(res.s), 2) if (len(res.s) - 1) % 2 == 0 else np.arange(len(res.s))
    profile = optimize_feed(res.s[idx], res.dq[idx], res.ddq[idx], res.dddq[idx], limits)
    result = sample(SepticInterpolant.from_resolution(res), profile.s, profile.b, limits,
                    micromill.control_period, micromill.axis_names)
    return path, res, result


@pytest.fixture(scope='module')
def quarter_helix(micromill, micromill_kin):
    return sampled_quarter_helix(micromill, micromill_kin, 0.01)


def tool_speed(kinematics, result):
    """The tool tip's speed over each control period, from the sent axis positions (forward
    kinematics, not the sampler's sdot): a chord over T is at most the arc over T, the mean
    feed over the period, never above the peak."""
    tip, _ = kinematics.forward_many(result.reference.position)
    return np.linalg.norm(np.diff(tip, axis=0), axis=1) / result.reference.period


def test_sampled_positions_follow_the_path_exactly(quarter_helix, micromill_kin):
    path, _, result = quarter_helix
    p_path, o_path = path.evaluate(result.s)
    for k in range(0, len(result.s), 5):
        p, o = micromill_kin.forward(result.reference.position[k])
        assert np.linalg.norm(p - p_path[k]) <= 1e-9
        angle = math.atan2(np.linalg.norm(np.cross(o, o_path[k])), o @ o_path[k])
        assert angle <= 1e-9


def test_sampled_references_keep_strokes_and_limits_by_finite_differences(quarter_helix, micromill):
    """The positions the axes are sent, held three periods at rest before and after, differenced
    at the control period against the config's limits. The k-th difference over T^k is the k-th
    derivative of the motion at a point within its k periods (mean value theorem), never above
    its peak, and their rounding (8 eps |x| / T^3) is under 1e-5 of the limits: the 0.1 % is
    sample()'s own acceptance (tolerance=1.001), the limit the sampler promises."""
    _, _, result = quarter_helix
    ref = result.reference
    T = micromill.control_period
    assert ref.period == T
    held = np.vstack([np.repeat(ref.position[:1], 3, 0), ref.position, np.repeat(ref.position[-1:], 3, 0)])
    jerk = []
    for i, axis in enumerate(micromill.axes):
        if axis.stroke:
            assert axis.stroke[0] <= ref.position[:, i].min() and ref.position[:, i].max() <= axis.stroke[1]
        x = held[:, i]
        assert np.abs(np.diff(x)).max() / T <= 1.001 * axis.limits.velocity
        assert np.abs(np.diff(x, 2)).max() / T**2 <= 1.001 * axis.limits.acceleration
        jerk.append(np.abs(np.diff(x, 3)).max() / T**3 / axis.limits.jerk)
        assert jerk[-1] <= 1.001
    assert max(jerk) >= 0.99                    # the jerk limit binds (measured 0.9991, y_c)


def test_reference_starts_and_ends_at_rest_on_the_path_ends(quarter_helix):
    path, res, result = quarter_helix
    ref = result.reference
    assert result.s[0] == 0.0 and result.s[-1] == pytest.approx(path.length, abs=1e-15)
    assert np.allclose(ref.position[0], res.q[0], rtol=0, atol=1e-15)
    assert np.allclose(ref.position[-1], res.q[-1], rtol=0, atol=1e-15)
    for a in (ref.velocity, ref.acceleration):
        assert not a[0].any() and not a[-1].any()


def test_velocity_reference_matches_the_position_differences(quarter_helix, micromill):
    _, _, result = quarter_helix
    ref = result.reference
    central = (ref.position[2:] - ref.position[:-2]) / (2 * ref.period)
    scale = np.array([a.limits.velocity for a in micromill.axes])
    assert np.max(np.abs(central - ref.velocity[1:-1]) / scale) < 1e-3


def test_no_faster_than_the_process_feed_limit(quarter_helix, micromill_kin):
    """The tool tip's speed (tool_speed). The tips lie on the path within 1e-13 m, their
    chords (<= 0.86 um) true to ~1e-8, and s is the path's arc length within 3e-10: 1e-6 holds
    them. (Here the jerk limit keeps the tip below the feed limit: peak 0.855 of it.)"""
    path, _, result = quarter_helix
    assert result.duration >= path.length / 0.01
    assert tool_speed(micromill_kin, result).max() <= 0.01 * (1 + 1e-6)


def test_where_the_feed_limit_binds_the_tool_keeps_it_between_the_nodes_too(micromill, micromill_kin):
    """At 4 mm/s the feed limit binds along the quarter helix (at 10 mm/s the jerk held it to
    8.55 mm/s, the test above): the tool's speed over every period (tool_speed) stays within F
    and reaches it. Before the
    feed bound's headroom (feed_shape.py) and the sampler's feed check it read 1.031 F near
    the rest ends."""
    _, _, result = sampled_quarter_helix(micromill, micromill_kin, 0.004)
    speed = tool_speed(micromill_kin, result)
    assert 0.999 * 0.004 <= speed.max() <= 0.004 * (1 + 1e-6)
    assert result.passes == 1 and result.feed_ratio <= 1.0 + 1e-12


def test_the_sampler_slows_a_profile_over_the_feed_limit_down_to_it():
    """A straight line (q = s) with every node at 10 mm/s against a feed limit of 8 mm/s (the
    axis allows 1 m/s): the feed is a velocity to the slow-down, which brings the line's own
    differences within 8 mm/s."""
    line = straight_line()
    feed_s = np.linspace(0.0, 1e-3, 11)
    limits = axis_limits(1.0)
    limits.feed = 0.008
    result = sample(line, feed_s, np.full(11, 0.01 ** 2), limits, 1e-4, ('x',))
    assert result.passes >= 2 and result.feed_ratio <= 1.001 and result.peak == result.feed_ratio
    assert np.abs(np.diff(result.reference.position[:, 0])).max() / 1e-4 <= 0.008 * 1.001
    with pytest.raises(LimitsExceeded, match='exceed the limits'):
        sample(line, feed_s, np.full(11, 0.01 ** 2), limits, 1e-4, ('x',), max_passes=1)


def fake_sampling(s, ratios, feed_ratios=None):
    from machine_ctrl.model.reference import Reference
    from trajectory.sampling import Sampling
    ref = Reference(('x',), 1e-4, np.zeros((len(s), 1)), np.zeros((len(s), 1)), np.zeros((len(s), 1)))
    return Sampling(ref, np.asarray(s, float), np.zeros(len(s)), 1.0, 1, np.zeros((1, 3)),
                    np.asarray(ratios, float), feed_ratios)


def test_limit_scales_lower_the_exceeded_limit_at_the_nodes_of_its_span_only():
    from trajectory.sampling import limit_scales
    feed_s = np.linspace(0.0, 20e-3, 201)                # 100 µm nodes
    s = np.linspace(0.0, 20e-3, 4001)
    ratios = np.full((4001, 3), 0.5)
    ratios[(s > 5.02e-3) & (s < 5.08e-3), 2] = 2.0       # jerk, between nodes 50 and 51
    ratios[(s > 15.03e-3) & (s < 15.04e-3), 1] = 1.1     # acceleration, between nodes 150 and 151
    ratios[(s > 10.01e-3) & (s < 10.02e-3), 0] = 0.995   # velocity just below its limit
    scales = limit_scales(fake_sampling(s, ratios), feed_s, margin=0.99)
    want = np.ones((201, 3))
    want[49:53, 2] = 0.99 / 2.0                          # the B-spline span's control points
    want[149:153, 1] = 0.99 / 1.1
    want[99:103, 0] = 0.99 / 0.995                       # up to the margin too
    assert np.allclose(scales, want, rtol=1e-12, atol=0)
    assert np.all(limit_scales(fake_sampling(s, np.full((4001, 3), 0.9)), feed_s, margin=0.99) == 1.0)
    sampling = fake_sampling(s, ratios)
    assert sampling.need.max() == pytest.approx(2.0 ** (2 / 3))     # j ~ b^(3/2)


def test_a_feed_at_its_limit_is_no_overshoot_only_a_feed_over_it_is():
    """A cruise at the feed limit (sdot / F = 0.9999, exact) with a jerk overshoot in one span:
    only the jerk's nodes are asked; where the feed is over F (1.05), the velocity factor is
    asked there, margin / 1.05 (it scales F in the re-solve)."""
    from trajectory.sampling import limit_scales
    feed_s = np.linspace(0.0, 20e-3, 201)
    s = np.linspace(0.0, 20e-3, 4001)
    ratios = np.full((4001, 3), 0.5)
    ratios[(s > 5.02e-3) & (s < 5.08e-3), 2] = 2.0       # jerk, between nodes 50 and 51
    feed = np.full(4001, 0.9999)
    want = np.ones((201, 3))
    want[49:53, 2] = 0.99 / 2.0
    assert np.allclose(limit_scales(fake_sampling(s, ratios, feed), feed_s, margin=0.99), want, rtol=1e-12, atol=0)
    feed[(s > 10.01e-3) & (s < 10.02e-3)] = 1.05         # over F, between nodes 100 and 101
    want[99:103, 0] = 0.99 / 1.05
    assert np.allclose(limit_scales(fake_sampling(s, ratios, feed), feed_s, margin=0.99), want, rtol=1e-12, atol=0)
    assert fake_sampling(s, ratios, feed).need.max() == pytest.approx(2.0 ** (2 / 3))     # jerk still the worst
    assert fake_sampling(s, ratios, feed).peak == pytest.approx(1.05)


def straight_line(length=1e-3, nodes=11):
    """One axis along s itself: q = s, q' = 1, q'' = q''' = 0."""
    s = np.linspace(0.0, length, nodes)
    one = np.ones((nodes, 1))
    return SepticInterpolant(s, s[:, None], one, 0 * one, 0 * one)


def axis_limits(velocity, acceleration=1e3, jerk=1e6):
    from types import SimpleNamespace
    return SimpleNamespace(velocity=np.array([velocity]), acceleration=np.array([acceleration]),
                           jerk=np.array([jerk]))


def test_the_sampling_loop_applies_the_rule_after_every_miss():
    from trajectory.sampling import sample_within
    line = straight_line()
    feed_s = np.linspace(0.0, 1e-3, 11)
    feed_b = np.full(11, 0.01 ** 2)                        # 10 mm/s
    calls = []

    def rule(result, b, scale):
        calls.append((result.passes, scale))
        return b, scale * 0.5

    # within at once: one pass, the rule never asked
    done = sample_within(line, feed_s, feed_b, axis_limits(1.0), 1e-4, ('x',), rule, 1.001, 4)
    assert done.within and done.sampling.passes == 1 and calls == [] and done.scale == 1.0
    # a tolerance no sampling meets: every pass misses, the rule runs after each one
    missed = sample_within(line, feed_s, feed_b, axis_limits(1.0), 1e-4, ('x',), rule, 0.0, 4)
    assert not missed.within and missed.sampling.passes == 4
    assert calls == [(1, 1.0), (2, 0.5), (3, 0.25), (4, 0.125)] and missed.scale == 0.0625


def test_the_global_stretch_meets_a_velocity_limit_below_the_feed():
    from trajectory.sampling import LimitsExceeded
    line = straight_line()
    feed_s = np.linspace(0.0, 1e-3, 11)
    feed_b = np.full(11, 0.01 ** 2)
    result = sample(line, feed_s, feed_b, axis_limits(0.004), 1e-4, ('x',))   # 4 mm/s < 10 mm/s
    assert result.passes >= 2 and np.max(result.peak_ratios) <= 1.001
    assert np.abs(np.diff(result.reference.position[:, 0])).max() / 1e-4 <= 0.004 * 1.001
    with pytest.raises(LimitsExceeded, match='exceed the limits'):
        sample(line, feed_s, feed_b, axis_limits(0.004), 1e-4, ('x',), max_passes=1)


def test_the_time_law_integral_is_the_time_scipy_integrates():
    """t(u) = the integral of du / f(u) (TimeLaw._integral, Gauss-Legendre) against scipy's
    adaptive quad of the same rate, on the interior feed intervals of a varying profile: an
    independent check of the quadrature the inversion below rests on."""
    from scipy.integrate import quad

    from trajectory.sampling import TimeLaw
    law = TimeLaw.from_profile(np.linspace(0.0, 1.0, 40), 1.0 + 0.5 * np.sin(np.linspace(0.0, 6.0, 40)))
    lo, hi = law.u_nodes[1:-2], law.u_nodes[2:-1]
    ours = law._integral(lo, hi)
    reference = [quad(lambda u: 1.0 / float(law.rate(np.array([u]))[0]), a, b, epsabs=0.0, epsrel=1e-13)[0]
                 for a, b in zip(lo, hi)]
    assert len(ours) == len(reference) == 37
    np.testing.assert_allclose(ours, reference, rtol=1e-10, atol=0)


@pytest.mark.parametrize('feed_b', [0.5 + np.sin(np.linspace(0.0, 3.0, 40)) ** 2,
                                    1e-3 + np.sin(np.linspace(0.0, 9.0, 40)) ** 2,     # dips 30x in feed
                                    # g tenfold within an interval: the quadrature's t(u) has a
                                    # slope off 1/f by ~2e-3, Newton converges linearly there
                                    np.abs(np.random.default_rng(0).normal(size=40)) ** 4],
                         ids=['varying', 'dips', 'spiky'])
def test_the_time_law_inverse_is_newtons_fixed_point_to_rounding(feed_b):
    """TimeLaw.u_at ([5/8] speed: a Hermite start, each entry stopped at rounding level or
    when its error estimate is) solves t(u) = t to the rounding of t, and equals plain
    Newton from the linear start, stepped 40 times (it then hops among neighbouring floats
    by t's rounding over f), within a few units in the last place of 1 (u is in [0, 1])."""
    from trajectory.sampling import TimeLaw
    law = TimeLaw.from_profile(np.linspace(0.0, 1.0, 40), feed_b)
    t = np.linspace(0.0, law.duration, 20001)
    i = np.clip(np.searchsorted(law.t_nodes, t, side='right') - 1, 0, len(law.t_nodes) - 2)
    lo, hi = law.u_nodes[i], law.u_nodes[i + 1]
    u = lo + (t - law.t_nodes[i]) / (law.t_nodes[i + 1] - law.t_nodes[i]) * (hi - lo)
    for _ in range(40):
        u = np.clip(u - (law.t_nodes[i] + law._integral(lo, u) - t) * law.rate(u), lo, hi)
    found = law.u_at(t)
    eps = np.finfo(float).eps
    assert np.abs(found - u).max() <= 8 * eps
    assert np.abs(law.t_nodes[i] + law._integral(lo, found) - t).max() <= 8 * eps * law.duration
