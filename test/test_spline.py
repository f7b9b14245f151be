"""Arc-length spline R(s) (thesis Eq. 3.12): interpolation, unit speed, unit axis,
derivatives, jerk continuity, circle length."""
import math

import numpy as np
import pytest

from trajectory import toolpath as tp
from trajectory.spline import ArcLengthPath

PATHS = {
    'circle_xy': tp.circle_xy,
    'spiral': tp.spiral,
    'helix': tp.helix,
    'surface': lambda: tp.sinusoidal_surface(stepover=1e-3),  # 11 rows keep it quick
}


@pytest.fixture(scope='module', params=sorted(PATHS))
def fitted(request):
    cl = PATHS[request.param]()
    return cl, ArcLengthPath.fit(cl)


def constant_axis(fitted):
    return np.ptp(fitted[0].axes, axis=0).max() == 0.0


def samples(path, n=2001):
    # interior samples that avoid knots (derivative finite differences straddle them otherwise)
    return np.linspace(0, path.length, n)[1:-1] + path.length / (7.3 * n)


def test_passes_through_input_points(fitted):
    cl, path = fitted
    P, O = path.evaluate(path.knot_s)
    assert np.abs(P - cl.positions).max() <= 1e-12  # m; interpolation, rounding only
    assert np.abs(O - cl.axes).max() <= 1e-12
    assert path.knot_s[0] == 0.0 and np.all(np.diff(path.knot_s) > 0)


def test_knot_arc_lengths_are_at_least_the_chords(fitted):
    cl, path = fitted
    chords = np.linalg.norm(np.diff(cl.positions, axis=0), axis=1)
    assert np.all(np.diff(path.knot_s) >= chords * (1 - 1e-12))


def test_unit_speed(fitted):
    _, path = fitted
    s = samples(path)
    P1, _ = path.derivatives(s, 1)
    assert np.abs(np.linalg.norm(P1, axis=1) - 1).max() <= 1e-6
    # independently of the derivative formulas: chord of a small step / step -> 1
    h = 1e-7
    P_plus, _ = path.evaluate(s + h)
    P_minus, _ = path.evaluate(s - h)
    assert np.abs(np.linalg.norm(P_plus - P_minus, axis=1) / (2 * h) - 1).max() <= 1e-6


def test_axis_is_unit(fitted):
    _, path = fitted
    _, O = path.evaluate(np.linspace(0, path.length, 5001))
    assert np.abs(np.linalg.norm(O, axis=1) - 1).max() <= 1e-12


def test_scalar_and_end_evaluation(fitted):
    cl, path = fitted
    P, O = path.evaluate(path.length)
    assert P.shape == (3,) and O.shape == (3,)
    np.testing.assert_allclose(P, cl.positions[-1], rtol=0, atol=1e-12)
    P1, O1 = path.derivatives(0.5 * path.length, 3)
    assert P1.shape == (3,) and O1.shape == (3,)


@pytest.mark.parametrize('order', [1, 2, 3])
def test_derivatives_match_finite_differences(fitted, order):
    _, path = fitted
    s = samples(path, 401)
    h = 1e-7  # m: truncation ~h^2 |d^(k+2)|/6 stays < 1e-5 relative at the surface's 0.5 mm turns
    plus = path.all_derivatives(s + h)[order - 1]
    minus = path.all_derivatives(s - h)[order - 1]
    exact = path.derivatives(s, order)
    for j, what in enumerate(('P', 'O')):
        if what == 'O' and constant_axis(fitted):
            # exactly zero up to rounding of the interpolated constant (rad / m^k)
            assert np.abs(exact[j]).max() <= 1e-3
            continue
        fd = (plus[j] - minus[j]) / (2 * h)
        scale = np.abs(exact[j]).max()  # relative to the largest derivative on the path
        assert np.abs(fd - exact[j]).max() <= 1e-5 * scale, (what, order)


def test_first_derivative_matches_evaluate(fitted):
    _, path = fitted
    s = samples(path, 401)
    h = 1e-7
    P_p, O_p = path.evaluate(s + h)
    P_m, O_m = path.evaluate(s - h)
    P1, O1 = path.derivatives(s, 1)
    assert np.abs((P_p - P_m) / (2 * h) - P1).max() <= 1e-5
    if not constant_axis(fitted):
        assert np.abs((O_p - O_m) / (2 * h) - O1).max() <= 1e-5 * np.abs(O1).max()


def test_jerk_is_continuous_at_knots(fitted):
    # A C2 (cubic) fit jumps by ~10 % of the jerk at its knots; a C3 fit changes by
    # |d4 P/ds4| * 2 eps only.
    _, path = fitted
    eps = 1e-9
    knots = path.knot_s[1:-1]
    for j in (0, 1) if not constant_axis(fitted) else (0,):
        after = path.derivatives(knots + eps, 3)[j]
        before = path.derivatives(knots - eps, 3)[j]
        scale = np.abs(after).max()
        assert np.abs(after - before).max() <= 1e-4 * scale


def test_circle_arc_length():
    path = ArcLengthPath.fit(tp.circle_xy(radius=4e-3))
    assert path.closed
    assert path.length == pytest.approx(2 * math.pi * 4e-3, rel=1e-9)
    # curvature 1/R and torsion-free: |P''| = 250 1/m, P''' = -P'/R^2
    s = samples(path, 101)
    P1, _ = path.derivatives(s, 1)
    P2, _ = path.derivatives(s, 2)
    P3, _ = path.derivatives(s, 3)
    np.testing.assert_allclose(np.linalg.norm(P2, axis=1), 250.0, rtol=1e-6)
    np.testing.assert_allclose(P3, -P1 * 250.0**2, rtol=0, atol=1e-6 * 250.0**2)


def test_helix_arc_length():
    # 3 turns of radius 5 mm, pitch 1 mm: L = 3 sqrt((2 pi R)^2 + p^2)
    path = ArcLengthPath.fit(tp.helix())
    assert path.length == pytest.approx(3 * math.hypot(2 * math.pi * 5e-3, 1e-3), rel=1e-8)


def test_rejects_bad_s_and_order():
    path = ArcLengthPath.fit(tp.circle_xy())
    with pytest.raises(ValueError, match='outside'):
        path.evaluate(-1e-3)
    with pytest.raises(ValueError, match='outside'):
        path.evaluate(path.length * 1.001)
    with pytest.raises(ValueError, match='finite'):
        path.evaluate(np.nan)
    with pytest.raises(ValueError, match='order must be 1, 2 or 3'):
        path.derivatives(0.0, 4)


def test_rejects_axis_flip():
    p = np.column_stack((np.arange(10) * 1e-3, np.zeros(10), np.zeros(10)))
    o = np.tile([0.0, 0.0, 1.0], (10, 1))
    o[5:] = [0.0, 0.0, -1.0]
    with pytest.raises(ValueError, match='tool axis turns too far between points 4 and 5'):
        ArcLengthPath.fit(tp.from_arrays(p, o))


def random_walk():
    """A path whose |P'| varies tenfold within a span: Gauss-Legendre's t(u) there has a
    slope off |P'| by ~1e-5, so Newton converges only linearly (a review's case)."""
    p = np.cumsum(np.random.default_rng(3).normal(size=(50, 3)) * 1e-3, axis=0)
    return tp.from_arrays(p, np.tile([0.0, 0.0, 1.0], (50, 1)))


@pytest.mark.parametrize('name', sorted(PATHS) + ['random_walk'])
def test_the_inversion_is_newtons_fixed_point_and_the_arc_length_to_rounding(name):
    """parameter(s) ([5/8] speed: a Hermite start, each s stopped at rounding level) equals
    plain Newton from the span's linear start, stepped 40 times, within four units in the
    last place of the parameter length (where Newton converges linearly, that one hops among
    neighbouring floats); and adaptive quadrature of |P'| (scipy's quad,
    not the module's Gauss-Legendre) gives back s from it."""
    from scipy.integrate import quad
    path = ArcLengthPath.fit(random_walk() if name == 'random_walk' else PATHS[name]())
    s = np.linspace(0.0, path.length, 20001)
    i = np.clip(np.searchsorted(path.knot_s, s, side='right') - 1, 0, len(path.knot_s) - 2)
    u0, u1, s0 = path.knot_u[i], path.knot_u[i + 1], path.knot_s[i]
    nodes, weights = np.polynomial.legendre.leggauss(16)
    u = u0 + (s - s0) / (path.knot_s[i + 1] - s0) * (u1 - u0)
    for _ in range(40):
        half = (u - u0) / 2
        arc = s0 + (np.linalg.norm(path.position_spline((u0 + half)[:, None] + half[:, None] * nodes, nu=1),
                                   axis=-1) * weights).sum(axis=-1) * half
        u = np.clip(u - (arc - s) / np.linalg.norm(path.position_spline(u, nu=1), axis=-1), u0, u1)
    found = path.parameter(s)
    assert np.abs(found - u).max() <= 4 * np.finfo(float).eps * path.knot_u[-1]
    if name == 'random_walk':
        return      # there the 16-point rule's arc length itself is off by up to ~1e-10 (module docstring)
    speed = lambda x: np.linalg.norm(path.position_spline(x, nu=1))  # noqa: E731
    for k in range(0, len(s), 1000):
        arc = s0[k] + quad(speed, u0[k], found[k], epsabs=0.0, epsrel=1e-13)[0]
        assert abs(arc - s[k]) <= 1e-15 * path.length, k


def test_the_hermite_start_reproduces_a_cubic():
    from trajectory.spline import hermite_cubic
    x = np.linspace(0.0, 1.0, 101)
    cubic = lambda x: 1.0 + 2.0 * x - 3.0 * x**2 + 4.0 * x**3  # noqa: E731
    slope = lambda x: 2.0 - 6.0 * x + 12.0 * x**2  # noqa: E731
    np.testing.assert_allclose(hermite_cubic(x, cubic(0.0), cubic(1.0), slope(0.0), slope(1.0)), cubic(x),
                               rtol=0, atol=1e-14)
