"""Redundancy resolution (trajectory/redundancy.py, Yuen thesis §3.3-3.8, Algorithm 1).

The paths are analytic; their derivatives come from a small truncated-Taylor (jet)
arithmetic written here, independently of the code under test.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from machine_ctrl.model.kinematics import orientation_basis
from trajectory.redundancy import (RedundancySettings, Resolution, _basis,
                                   initial_configuration, resolve)


class Jet:
    """Value and first three derivatives d^k/ds^k of a scalar function of s."""

    def __init__(self, d):
        self.d = np.asarray(d, dtype=float)

    @staticmethod
    def const(c):
        return Jet([c, 0.0, 0.0, 0.0])

    def __add__(self, other):
        other = other if isinstance(other, Jet) else Jet.const(other)
        return Jet(self.d + other.d)

    __radd__ = __add__

    def __neg__(self):
        return Jet(-self.d)

    def __sub__(self, other):
        return self + (-other)

    def __mul__(self, other):
        if not isinstance(other, Jet):
            return Jet(self.d * other)
        f, g = self.d, other.d
        return Jet([f[0] * g[0], f[1] * g[0] + f[0] * g[1],
                    f[2] * g[0] + 2 * f[1] * g[1] + f[0] * g[2],
                    f[3] * g[0] + 3 * f[2] * g[1] + 3 * f[1] * g[2] + f[0] * g[3]])

    __rmul__ = __mul__

    def _chain(self, f0, f1, f2, f3):
        """Faa di Bruno to third order for an outer function with derivatives f0..f3."""
        u1, u2, u3 = self.d[1:]
        return Jet([f0, f1 * u1, f2 * u1**2 + f1 * u2, f3 * u1**3 + 3 * f2 * u1 * u2 + f1 * u3])

    def sin(self):
        s, c = math.sin(self.d[0]), math.cos(self.d[0])
        return self._chain(s, c, -s, -c)

    def cos(self):
        s, c = math.sin(self.d[0]), math.cos(self.d[0])
        return self._chain(c, -s, -c, s)


class JetPath:
    """Path interface of trajectory.redundancy from a function s-jet -> (P jets, O jets)."""

    def __init__(self, length, function):
        self.length, self._f = length, function

    def _eval(self, s):
        p, o = self._f(Jet([s, 1.0, 0.0, 0.0]))
        return np.array([c.d for c in p]).T, np.array([c.d for c in o]).T   # (4, 3) each

    def _order(self, s, order):
        """d^order P/ds^order and d^order O/ds^order at a scalar s or an array of s."""
        if np.ndim(s) == 0:
            p, o = self._eval(float(s))
            return p[order], o[order]
        rows = [self._eval(float(x)) for x in s]
        return np.array([p[order] for p, _ in rows]), np.array([o[order] for _, o in rows])

    def evaluate(self, s):
        return self._order(s, 0)

    def derivatives(self, s, order):
        return self._order(s, order)

    def tangents(self, s):
        return [self._order(s, 0), self._order(s, 1)]


def circle(radius, centre, turns=1.0):
    """x-y circle P = c + R (cos(s/R), sin(s/R), 0), O = +z (thesis §3.4)."""
    def f(s):
        t = s * (1.0 / radius)
        return ((t.cos() * radius + centre[0], t.sin() * radius + centre[1], Jet.const(centre[2])),
                (Jet.const(0.0), Jet.const(0.0), Jet.const(1.0)))
    return JetPath(2 * math.pi * radius * turns, f)


def tilted_helix(radius, pitch, turns, centre, shear=0.05):
    """Helix of `turns` turns, its axis tilted by `shear` (x += shear z), with a tool axis
    O = (cos a sin g, -sin a, cos a cos g) wobbling twice per turn: a = 3.5 mrad sin(2t),
    g = 0.5 mrad + 3 mrad cos(2t), i.e. at most 0.29 deg from vertical."""
    k = math.hypot(radius, pitch / (2 * math.pi))

    def f(s):
        t = s * (1.0 / k)
        z = t * (pitch / (2 * math.pi))
        p = (t.cos() * radius + z * shear + centre[0], t.sin() * radius + centre[1], z + centre[2])
        a = (t * 2.0).sin() * 3.5e-3
        g = (t * 2.0).cos() * 3e-3 + 0.5e-3
        o = (a.cos() * g.sin(), -a.sin(), a.cos() * g.cos())
        return p, o
    return JetPath(2 * math.pi * turns * k, f)


@pytest.fixture(scope='module')
def home_tip(micromill, micromill_kin):
    return micromill_kin.forward(np.array(micromill.home))[0]


def task_errors(kin, path, res):
    ep, eo = [], []
    for s, q in zip(res.s, res.q):
        p, o = kin.forward(q)
        pd, od = path.evaluate(s)
        ep.append(np.linalg.norm(p - pd))
        eo.append(math.atan2(np.linalg.norm(np.cross(o, od)), o @ od))
    return np.array(ep), np.array(eo)


def strokes(machine):
    lo = np.array([a.stroke[0] if a.stroke else -np.inf for a in machine.axes])
    hi = np.array([a.stroke[1] if a.stroke else np.inf for a in machine.axes])
    return lo, hi


def test_jet_path_derivatives_match_finite_differences():
    # guards the test paths themselves
    path = tilted_helix(2e-3, 0.5e-3, 1, (0, 0, 0))
    h = 1e-5
    for s in (1e-3, 5e-3):
        for order in (1, 2, 3):
            lo = np.concatenate(path.derivatives(s - h, order - 1) if order > 1 else path.evaluate(s - h))
            hi = np.concatenate(path.derivatives(s + h, order - 1) if order > 1 else path.evaluate(s + h))
            exact = np.concatenate(path.derivatives(s, order))
            assert np.allclose((hi - lo) / (2 * h), exact, rtol=1e-5, atol=1e-5 * np.abs(exact).max())


def test_basis_is_the_kinematics_basis():
    rng = np.random.default_rng(3)
    for _ in range(20):
        o = rng.normal(size=3)
        o /= np.linalg.norm(o)
        assert np.allclose(_basis(o), orientation_basis(o), atol=1e-15)


@pytest.fixture(scope='module')
def helix_run(micromill, micromill_kin, home_tip):
    path = tilted_helix(2e-3, 0.5e-3, 2, home_tip + np.array([-2e-3, 0, -0.5e-3]))
    return path, resolve(path, micromill_kin, micromill, RedundancySettings())


def test_helix_tracks_the_path_inside_the_strokes(micromill, micromill_kin, helix_run):
    path, res = helix_run
    assert isinstance(res, Resolution)
    n = len(res.s)
    assert res.q.shape == res.dq.shape == res.ddq.shape == res.dddq.shape == (n, 9)
    assert res.s[0] == 0.0 and res.s[-1] == pytest.approx(path.length, rel=1e-15)
    assert np.allclose(np.diff(res.s), path.length / (n - 1))
    ep, eo = task_errors(micromill_kin, path, res)
    assert ep.max() <= 1e-9 and eo.max() <= 1e-9
    assert res.max_position_error == pytest.approx(ep.max(), abs=1e-13)
    assert res.max_orientation_error <= 1e-9
    lo, hi = strokes(micromill)
    assert np.all(res.q >= lo) and np.all(res.q <= hi)
    # the redundant pairs really share the motion: the coarse axes carry the mm
    assert np.ptp(res.q[:, 0]) > 3e-3 and np.ptp(res.q[:, 1]) > 3e-3


def test_drift_without_projection_stays_small(micromill, micromill_kin, home_tip):
    # RK4 + the K_e correction alone (Eq. 3.27, no Newton projection): thesis Fig. 3.7 level
    path = tilted_helix(2e-3, 0.5e-3, 1, home_tip + np.array([-2e-3, 0, -0.5e-3]))
    res = resolve(path, micromill_kin, micromill, RedundancySettings(projection_iterations=0))
    ep, eo = task_errors(micromill_kin, path, res)
    assert ep.max() <= 1e-9 and eo.max() <= 1e-9


XY = ('x_c', 'y_c', 'x_f', 'y_f')


def circle_run(micromill, kin, home_tip, beta):
    path = circle(4e-3, home_tip)     # thesis §3.4: R = 4 mm in the x-y plane
    settings = RedundancySettings(active_axes=XY, beta=beta)
    return path, resolve(path, kin, micromill, settings)


def test_circle_stroke_cost_keeps_fine_axes_inside(micromill, micromill_kin, home_tip):
    names = micromill.axis_names
    xf, yf = names.index('x_f'), names.index('y_f')
    frozen = [names.index(a) for a in names if a not in XY]
    _, free = circle_run(micromill, micromill_kin, home_tip, beta=0.0)         # Fig. 3.2
    path, held = circle_run(micromill, micromill_kin, home_tip, beta=5e-5)     # Fig. 3.3
    # without the cost the minimum-norm rate splits the motion equally: x_f = x_c motion,
    # +-2 mm of a 4 mm circle, far outside the +-100 µm fine stroke
    assert np.abs(free.q[:, [xf, yf]]).max() > 1e-3
    assert np.allclose(np.ptp(free.q[:, xf]), 4e-3, rtol=1e-6)
    assert np.abs(held.q[:, [xf, yf]]).max() < 100e-6
    for res in (free, held):
        assert np.all(res.q[:, frozen] == res.q[0, frozen])
        assert res.max_position_error <= 1e-9
    ep, _ = task_errors(micromill_kin, path, held)
    assert ep.max() <= 1e-9


def test_circle_minimum_norm_derivatives_are_exact(micromill, micromill_kin, home_tip):
    # beta = 0, a, b, c frozen at 0: P_x = -x_c - x_f + const, so the minimum-norm rate is
    # d^k x_c/ds^k = d^k x_f/ds^k = -d^k P_x/ds^k / 2 (and the same for y), exactly.
    path, res = circle_run(micromill, micromill_kin, home_tip, beta=0.0)
    names = micromill.axis_names
    for k, out in ((1, res.dq), (2, res.ddq), (3, res.dddq)):
        expected = np.array([path.derivatives(s, k)[0][:2] for s in res.s]) * -0.5
        scale = np.abs(expected).max()                  # 0.5, 125 1/m, 3.1e4 1/m²
        for axis, col in (('x_c', 0), ('x_f', 0), ('y_c', 1), ('y_f', 1)):
            err = np.abs(out[:, names.index(axis)] - expected[:, col]).max()
            assert err <= 1e-6 * scale, (axis, k, err / scale)


def fd_derivatives(res, stride):
    """4th-order central differences of the resolved q over s (spacing stride * Δs), on the
    strided samples 3 .. M-4 (M samples)."""
    q, h = res.q[::stride], (res.s[stride] - res.s[0])
    m = len(q)

    def at(j):
        return q[3 + j:m - 3 + j]
    d1 = (-at(2) + 8 * at(1) - 8 * at(-1) + at(-2)) / (12 * h)
    d2 = (-at(2) + 16 * at(1) - 30 * at(0) + 16 * at(-1) - at(-2)) / (12 * h**2)
    d3 = (-at(3) + 8 * at(2) - 13 * at(1) + 13 * at(-1) - 8 * at(-2) + at(-3)) / (8 * h**3)
    return d1, d2, d3


def assert_derivatives_match(res, tolerances, skip):
    """dq, ddq, dddq of the resolution against 4th-order differences of its samples q[n]
    (spacing 2 Δs), relative to max|d^k q/ds^k| of each axis, after `skip` strided samples."""
    stride = 2
    d1, d2, d3 = fd_derivatives(res, stride)
    for k, fd, out, tolerance in zip((1, 2, 3), (d1, d2, d3), (res.dq, res.ddq, res.dddq),
                                     tolerances):
        ours = out[::stride][3:-3][skip:]
        scale = np.abs(ours).max(axis=0)
        scale[scale == 0] = 1.0
        rel = (np.abs(ours - fd[skip:]) / scale).max()
        assert rel < tolerance, (k, rel)


def test_derivatives_match_finite_differences_of_q_helix(helix_run):
    # Δs = 20 µm: the differences of the samples themselves are off by up to 3e-5 / 3e-4 /
    # 4.5e-3 of max|d^k q/ds^k| (k = 1, 2, 3; worst on y_f: the differences' truncation and
    # the RK4 discretization of the stiff nullspace mode, rate beta/h_f² = 5e3 1/m; they
    # shrink ~10x when Δs halves, see the next test). The first 0.4 mm (start-up transient of
    # that mode) are left out.
    _, res = helix_run
    assert_derivatives_match(res, (1e-4, 1e-3, 1e-2), skip=10)


def test_derivatives_match_finite_differences_of_q_fine_step(micromill, micromill_kin, home_tip):
    # Δs = 5 µm over a quarter of the 4 mm circle with the stroke cost: the sample
    # differences are accurate to ~1e-5 (k = 1, 2) and ~2e-4 (k = 3) of max|d^k q/ds^k|
    path = circle(4e-3, home_tip, turns=0.25)
    settings = RedundancySettings(active_axes=XY, beta=5e-5, step=5e-6)
    res = resolve(path, micromill_kin, micromill, settings)
    assert_derivatives_match(res, (1e-5, 1e-4, 5e-4), skip=40)


def test_initial_configuration_matches_path_start(micromill, micromill_kin, home_tip):
    path = tilted_helix(2e-3, 0.5e-3, 1, home_tip + np.array([-2e-3, 0, -0.5e-3]))
    q0 = initial_configuration(path, micromill_kin, micromill)
    p, o = micromill_kin.forward(q0)
    pd, od = path.evaluate(0.0)
    assert np.linalg.norm(p - pd) < 1e-12 and np.linalg.norm(o - od) < 1e-12
    # the stroke weighting leaves the fine linear axes essentially at home
    assert np.abs(q0[3:6]).max() < 1e-8


def test_bad_inputs_are_rejected(micromill, micromill_kin, home_tip):
    path = circle(4e-3, home_tip)
    with pytest.raises(ValueError, match='step must be a positive finite number, got 0.0'):
        RedundancySettings(step=0.0)
    with pytest.raises(ValueError, match='beta must be a non-negative finite number, got -1.0'):
        RedundancySettings(beta=-1.0)
    with pytest.raises(ValueError, match='active_axes: unknown axis names'):
        resolve(path, micromill_kin, micromill, RedundancySettings(active_axes=('x_q',)))
    with pytest.raises(ValueError, match='q0 must be 9 finite axis positions'):
        resolve(path, micromill_kin, micromill, q0=np.full(9, np.nan))
    # z cannot follow a path away from z with x, y only
    away = circle(4e-3, home_tip + np.array([0, 0, 1e-3]))
    with pytest.raises(ValueError, match='cannot reach R\\(0\\) with the active axes'):
        resolve(away, micromill_kin, micromill, RedundancySettings(active_axes=XY))


def test_grid_stencils_are_exact_for_degree_6_polynomials_and_converge_on_a_sine():
    from trajectory.redundancy import _along_s
    poly = np.polynomial.Polynomial([0.2, -1.0, 0.5, 3.0, -2.0, 0.7, -0.4])
    for h in (0.1, 0.013):
        s = np.arange(12) * h
        f = np.column_stack((poly(s), 2.0 * poly(s)))
        for order in (1, 2):
            exact = poly.deriv(order)(s)
            got = _along_s(f, h, order)
            assert np.allclose(got[:, 0], exact, rtol=0, atol=1e-6 * np.abs(exact).max())
            assert np.allclose(got[:, 1], 2.0 * exact, rtol=0, atol=2e-6 * np.abs(exact).max())
    # centred 7-point stencils are O(h^6): halving h divides the error by ~64
    errors = []
    for h in (0.2, 0.1):
        s = np.arange(40) * h
        got = _along_s(np.sin(s)[:, None], h, 2)[10:-10, 0]
        errors.append(np.abs(got + np.sin(s[10:-10])).max())
    assert 40 < errors[0] / errors[1] < 90


class CountingKinematics:
    """Kinematics wrapper counting forward_and_jacobian calls; without packed chains, so
    resolve runs its interpreted loop on these calls."""

    def __init__(self, kin):
        self.kin, self.calls = kin, 0

    def packed_chains(self):
        return None

    def forward_and_jacobian(self, q):
        self.calls += 1
        return self.kin.forward_and_jacobian(q)


def test_five_kinematics_evaluations_per_step(micromill, micromill_kin, home_tip):
    # the four RK4 stages and the projection's check, whose FK and Jacobian the next step's
    # first stage reuses; the derivative outputs cost none
    path = tilted_helix(2e-3, 0.5e-3, 0.1, home_tip + np.array([-2e-3, 0, -0.5e-3]))
    q0 = initial_configuration(path, micromill_kin, micromill)
    counting = CountingKinematics(micromill_kin)
    res = resolve(path, counting, micromill, q0=q0)
    steps = len(res.s) - 1
    assert steps > 50
    assert counting.calls <= 5 * steps + 3


def test_a_breakdown_is_named_out_of_stroke_or_singular(micromill):
    from trajectory.redundancy import ResolutionFailed, _failure
    s = np.arange(5) * 1e-3
    inside = np.zeros((5, len(micromill.axes)))
    inside[:, 0] = [0.0, 0.01, 0.02, 0.03, 0.04]          # x_c, stroke +-0.05 m
    failure = _failure(micromill, s, inside)              # never left the strokes
    assert isinstance(failure, ResolutionFailed) and isinstance(failure, ValueError)
    assert failure.kind == 'singular' and failure.s == 4e-3 and 's = 4 mm' in str(failure)
    runaway = inside.copy()
    runaway[2:, 0] = [0.0497, 3e11, np.nan]                 # at the stroke end, then away
    runaway[2, 3] = 50e-6                                    # x_f halfway to its +-100 um end: not named
    failure = _failure(micromill, s, runaway)
    assert failure.kind == 'out_of_stroke' and failure.s == 2e-3
    assert failure.reason == ('the redundancy resolution cannot keep the axes inside their strokes at s = 2 mm: '
                              'x_c at 0.0497 m, 300 µm from the end of its stroke [-0.05, 0.05] m')
    start_outside = inside.copy()
    start_outside[:, 1] = -0.2
    failure = _failure(micromill, s, start_outside)
    assert failure.kind == 'out_of_stroke' and failure.s == 0.0
    assert failure.reason == ('the start configuration is outside the strokes: '
                              'y_c at -0.2 m, outside its stroke [-0.05, 0.05] m by 150 mm')


class KnotPath:
    """Only the arc lengths of the CL points (spline.ArcLengthPath.knot_s)."""
    knot_s = np.array([0.0, 1e-3, 2.5e-3, 4e-3])


def test_a_breakdown_names_the_cl_points_around_it(micromill):
    from trajectory.redundancy import _failure, where_on
    assert where_on(KnotPath(), 1.7e-3) == 'between points 1 and 2 (s = 1.7 mm)'
    assert where_on(KnotPath(), 2.5e-3) == 'at point 2 (s = 2.5 mm)'
    assert where_on(KnotPath(), 4e-3) == 'between points 2 and 3 (s = 4 mm)'       # the end: the last span
    assert where_on(None, 4e-3) == 'at s = 4 mm'
    s = np.array([0.0, 1e-3, 1.7e-3])
    qs = np.zeros((3, len(micromill.axes)))
    failure = _failure(micromill, s, qs, KnotPath())
    assert failure.kind == 'singular' and 'singular between points 1 and 2 (s = 1.7 mm)' in failure.reason


def test_the_pose_solver_reaches_poses_and_finds_the_nearest_inside_the_strokes(micromill, micromill_kin,
                                                                                 home_tip):
    from trajectory.redundancy import PoseSolver
    solver = PoseSolver(micromill_kin, micromill)
    z = np.array([0.0, 0.0, 1.0])
    # 1 mm beside the home tool tip: reached, the coarse axis moving (fine axes near home)
    q, ep, eo = solver.weighted(home_tip + [1e-3, 0.0, 0.0], z, micromill.home)
    assert ep <= 1e-14 and eo <= 1e-14 and abs(q[0] + 1e-3) < 2e-6 and abs(q[3]) < 2e-6
    # tilted 0.1 rad about y: b_f (stroke +-0.5 deg = 8.7 mrad) would have to turn 0.1 rad
    tilted = np.array([math.sin(0.1), 0.0, math.cos(0.1)])
    q, ep, eo = solver.weighted(home_tip, tilted, micromill.home)
    assert ep <= 1e-14 and eo <= 1e-14 and q[7] == pytest.approx(-0.1, abs=1e-9)
    q, ep, eo = solver.inside(home_tip, tilted, q)
    # nearest inside: c_f turns the table so that a_f and b_f both tilt at their stroke ends,
    # arccos(cos a cos b) = 12.3 mrad of the 0.1 rad; the rest is missing
    end = math.radians(0.5)
    assert np.abs(q[6:8]).tolist() == pytest.approx([end, end], abs=1e-12)
    assert eo == pytest.approx(0.1 - math.acos(math.cos(end) ** 2), abs=1e-6)
    # 60 mm beside it: x_c alone cannot (stroke +-50 mm) but turning the table (c_f) can
    far = home_tip + [-0.06, 0.0, 0.0]
    q, ep, eo = solver.inside(far, z, solver.weighted(far, z, micromill.home)[0])
    assert ep <= 1e-9 and eo <= 1e-9
    assert all(a.in_stroke(v) for a, v in zip(micromill.axes, q))
