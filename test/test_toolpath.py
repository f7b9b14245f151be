"""CL data input: CLData validation, CSV reader, quaternion helper, built-in paths."""
import math

import numpy as np
import pytest

from trajectory import toolpath as tp
from trajectory.toolpath import MIN_POINTS, CLData


def line(n=MIN_POINTS):
    p = np.column_stack((np.arange(n) * 1e-3, np.zeros(n), np.zeros(n)))
    o = np.tile([0.0, 0.0, 2.0], (n, 1))  # not unit on purpose
    return p, o


# ---------------------------------------------------------------- CLData

def test_axes_are_normalized_and_arrays_frozen():
    p, o = line()
    cl = tp.from_arrays(p, o)
    np.testing.assert_array_equal(cl.axes, np.tile([0.0, 0.0, 1.0], (MIN_POINTS, 1)))
    with pytest.raises(ValueError):
        cl.positions[0, 0] = 1.0


@pytest.mark.parametrize('mutate, message', [
    (lambda p, o: (p[:, :2], o), r'positions must have shape \(N, 3\)'),
    (lambda p, o: (p, o[:, :2]), r'axes must have shape \(N, 3\)'),
    (lambda p, o: (p, o[:-1]), '6 positions but 5 tool axes'),
    (lambda p, o: (p[:-1], o[:-1]), '5 points, need at least 6'),
    (lambda p, o: (np.where(np.arange(6)[:, None] == 3, np.nan, p), o), 'point 3: position is not finite'),
    (lambda p, o: (p, np.where(np.arange(6)[:, None] == 5, np.inf, o)), 'point 5: tool axis is not finite'),
    (lambda p, o: (p, np.where(np.arange(6)[:, None] == 2, 0.0, o)), 'point 2: zero-length tool axis'),
    (lambda p, o: (p, np.where(np.arange(6)[:, None] == 2, 5e-10, o)), 'point 2: zero-length tool axis'),
    (lambda p, o: (np.where(np.arange(6)[:, None] == 4, 1e308, p), o),
     r'point 4: position \[1e\+308, 1e\+308, 1e\+308\] m has a coordinate beyond \+-1e\+150 m, no distance can be '
     r'taken of it'),
    (lambda p, o: (np.where(np.arange(6)[:, None] == 1, -1.01e150, p), o), 'point 1: position .* beyond'),
    (lambda p, o: (np.vstack((p[:5], p[4:5])), o), r'point 5 repeats point 4: points 4 and 5 are 0 m apart '
                                                   r'\(need >= 1e-09 m\)'),
    (lambda p, o: (np.vstack((p[:5], p[4:5] + [1e-12, 0.0, 0.0])), o),
     r'point 5 repeats point 4: points 4 and 5 are 1e-12 m apart \(need >= 1e-09 m\)'),
])
def test_cldata_rejections(mutate, message):
    p, o = line()
    with pytest.raises(ValueError, match=message) as e:
        CLData(*mutate(p, o))
    assert '\n' not in str(e.value)


def test_extreme_tool_axis_lengths_are_normalized_without_overflow():
    """A tool axis of any finite length is a direction (|(1e308, 1e308, 0)| overflows a plain
    norm); a tip 1e150 m out is still accepted (the planner refuses it, naming the machine's
    reach)."""
    p, o = line()
    p[-1] = [1e150, -1e150, 1e150]
    o[0], o[1], o[2] = [1e308, 1e308, 0.0], [0.0, -1e-8, 0.0], [3e-9, 0.0, 4e-9]
    with np.errstate(all='raise'):
        cl = CLData(p, o)
    np.testing.assert_allclose(cl.axes[:3], [[math.sqrt(0.5), math.sqrt(0.5), 0], [0, -1, 0], [0.6, 0, 0.8]],
                               rtol=1e-15)


def test_six_points_are_the_fewest_and_they_fit_a_quintic():
    # a quintic interpolating spline needs k + 1 = 6 points: the fit of six works, the CL data
    # of five are refused
    from trajectory.spline import DEGREE, ArcLengthPath
    assert MIN_POINTS == DEGREE + 1 == 6
    t = np.linspace(0.0, 1.0, 6)
    p = np.column_stack((1e-3 * np.cos(t), 1e-3 * np.sin(t), np.zeros(6)))
    path = ArcLengthPath.fit(tp.from_arrays(p, np.tile([0.0, 0.0, 1.0], (6, 1))))
    np.testing.assert_allclose(path.evaluate(path.knot_s)[0], p, atol=1e-17)
    with pytest.raises(ValueError, match='5 points, need at least 6'):
        tp.from_arrays(p[:5], np.tile([0.0, 0.0, 1.0], (5, 1)))


def test_closed_path_is_not_a_repeat():
    t = np.linspace(0, 2 * np.pi, 9)
    p = np.column_stack((np.cos(t), np.sin(t), 0 * t)) * 1e-3
    p[-1] = p[0]
    CLData(p, np.tile([0.0, 0.0, 1.0], (9, 1)))


# ---------------------------------------------------------------- quaternions

def test_axes_from_quaternions_hand_computed():
    h = math.sqrt(0.5)
    a = math.radians(0.3)
    q = [[0, 0, 0, 1],                                   # identity: z stays z
         [h, 0, 0, h],                                   # +90 deg about x: z -> -y
         [0, math.sin(a / 2), 0, math.cos(a / 2)],       # a about y: z -> (sin a, 0, cos a)
         [0, 0, 1.004 * h, 1.004 * h],                   # about z, norm 1.004 (within tf2's tolerance)
         [0, 1, 0, 0]]                                   # 180 deg about y: z -> -z
    expected = [[0, 0, 1], [0, -1, 0], [math.sin(a), 0, math.cos(a)], [0, 0, 1], [0, 0, -1]]
    np.testing.assert_allclose(tp.axes_from_quaternions(q), expected, atol=1e-15)


UNIT = [0.0, 0.0, 0.0, 1.0]


@pytest.mark.parametrize('q, message', [
    ([[0, 0, 0]], r'shape \(N, 4\)'),
    ([[0, 0, 0, 0]], 'pose 0: orientation quaternion has zero length, not unit'),
    ([UNIT, [np.nan, 0, 0, 1]], r'pose 1: orientation quaternion is not finite \(NaN or inf\)'),
    ([UNIT] * 3 + [[0, 0, 0, 0.5]], r'pose 3: orientation quaternion has norm 0.5, not unit '
                                    r'\(\|x² \+ y² \+ z² \+ w² - 1\| must be below 0.01\)'),
    ([UNIT, [0, 0, 0, 1.006]], 'pose 1: orientation quaternion has norm 1.006, not unit'),   # squared: 1.012
    ([UNIT, [0, 0, 0, 2]], 'pose 1: orientation quaternion has norm 2, not unit'),
    ([UNIT, [0, 0, 1e308, 1e308]], 'pose 1: orientation quaternion has norm inf, not unit'),
])
def test_axes_from_quaternions_rejects(q, message):
    with pytest.raises(ValueError, match=message) as e, np.errstate(all='raise'):
        tp.axes_from_quaternions(q)
    if isinstance(e.value, tp.CLDataError):
        assert e.value.index == len(q) - 1


# ---------------------------------------------------------------- CSV

def test_csv_round_trip(tmp_path):
    cl = tp.helix()
    tp.write_csv(tmp_path / 'h.csv', cl)
    back = tp.read_csv(tmp_path / 'h.csv')
    np.testing.assert_array_equal(back.positions, cl.positions)
    np.testing.assert_array_equal(back.axes, cl.axes)


def test_csv_column_order_comments_and_blank_lines(tmp_path):
    rows = '\n'.join(f'0,0,1,{i}e-3,0,0' for i in range(8))
    f = tmp_path / 'a.csv'
    f.write_text(f'# comment\noi,oj,ok,px,py,pz\n\n{rows}\n')
    cl = tp.read_csv(f)
    np.testing.assert_array_equal(cl.positions[:, 0], np.arange(8) * 1e-3)
    np.testing.assert_array_equal(cl.axes[:, 2], 1.0)


GOOD = [f'{i}e-3,0,0,0,0,1' for i in range(8)]


@pytest.mark.parametrize('text, message', [
    ('px,py,pz,oi,oj\n' + '\n'.join(GOOD), 'line 1: missing column.*ok'),
    ('px,py,pz,oi,oj,ok,extra\n' + '\n'.join(GOOD), 'line 1: unknown or repeated column'),
    ('px,py,pz,oi,oj,ok\n' + '\n'.join(GOOD[:3] + ['1e-2,0,zero,0,0,1'] + GOOD[3:]),
     "line 5: not a number: 'zero'"),
    ('px,py,pz,oi,oj,ok\n' + '\n'.join(GOOD[:2] + ['1e-2,0,0,0,0'] + GOOD[2:]), 'line 4: 5 values, expected 6'),
    ('px,py,pz,oi,oj,ok\n' + '\n'.join(GOOD[:5]), '5 data rows, need at least 6'),
    ('', 'no header line'),
    ('px,py,pz,oi,oj,ok\n' + '\n'.join(GOOD[:3] + ['nan,0,0,0,0,1'] + GOOD[3:]), 'line 5: .*not finite'),
    ('px,py,pz,oi,oj,ok\n' + '\n'.join(GOOD[:3] + ['9,0,0,0,0,0'] + GOOD[3:]), 'line 5: .*zero-length tool axis'),
    ('px,py,pz,oi,oj,ok\n' + '\n'.join(GOOD[:3] + [GOOD[2]] + GOOD[3:]), 'line 5: point 3 repeats point 2'),
])
def test_csv_errors(tmp_path, text, message):
    f = tmp_path / 'bad.csv'
    f.write_text(text)
    with pytest.raises(ValueError, match=message) as e:
        tp.read_csv(f)
    assert str(e.value).startswith(f'{f}: ') and '\n' not in str(e.value)


def test_csv_missing_file(tmp_path):
    with pytest.raises(ValueError, match='cannot read'):
        tp.read_csv(tmp_path / 'nope.csv')


# ---------------------------------------------------------------- built-in paths

LIMIT = math.radians(0.3)  # issue [3/7]: well inside the +-0.5 deg a_f/b_f strokes


@pytest.mark.parametrize('name', sorted(tp.BUILTIN))
def test_builtin_paths_are_valid_and_reachable(name):
    cl = tp.builtin(name)
    assert isinstance(cl, CLData) and len(cl) >= MIN_POINTS
    tilt = np.arccos(np.clip(cl.axes[:, 2], -1, 1))
    assert tilt.max() <= LIMIT
    # within the +-50 mm x/y strokes of the micromill (seed-notes.md)
    assert np.abs(cl.positions[:, :2]).max() < 50e-3


def test_circle_dimensions():
    cl = tp.circle_xy()
    np.testing.assert_allclose(np.hypot(cl.positions[:, 0], cl.positions[:, 1]), 4e-3, rtol=1e-15)
    np.testing.assert_array_equal(cl.positions[:, 2], 0.0)
    np.testing.assert_array_equal(cl.axes, np.tile([0.0, 0.0, 1.0], (len(cl), 1)))
    np.testing.assert_array_equal(cl.positions[0], cl.positions[-1])


def test_sinusoidal_surface_seed_values():
    cl = tp.sinusoidal_surface(stepover=0.5e-3)  # coarse stepover keeps the test short
    # constant 0.15 deg tilt (thesis section 6.2)
    np.testing.assert_allclose(np.degrees(np.arccos(cl.axes[:, 2])), 0.15, rtol=1e-9)
    # the ball (radius 198.5 um) centre = tip + r O lies r above the surface along its normal;
    # check the ball bottom height range: surface peak-to-peak 500 um
    ball_centre = cl.positions + 198.5e-6 * cl.axes
    inside = (cl.positions[:, 0] > 0) & (cl.positions[:, 0] < 10e-3)
    z_top = ball_centre[inside, 2] - 198.5e-6
    assert 0.45e-3 < z_top.max() - z_top.min() <= 0.5e-3 + 1e-9
    assert cl.positions[:, 1].max() == pytest.approx(10e-3, abs=0.1e-3)
    # default is the seed's 10 um stepover: 1001 rows over 10 mm
    full = tp.sinusoidal_surface()
    assert len(full) > 1001 * 8


def test_builtin_unknown_name():
    with pytest.raises(ValueError, match="unknown toolpath 'square'"):
        tp.builtin('square')
