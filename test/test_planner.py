"""plan(): fit -> resolve -> feed -> sample, its result statuses, and `machine-ctrl plan`."""
import json
import math
import re

import numpy as np
import pytest

from machine_ctrl.app import cli
from machine_ctrl.model.kinematics import Kinematics
from trajectory import planner, reach, toolpath
from trajectory.planner import PlanError, PlanStatus, plan
from trajectory.redundancy import RedundancySettings


@pytest.fixture(scope='module')
def short_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp('cl') / 'quarter_helix.csv'
    toolpath.write_csv(path, toolpath.helix(turns=0.25))
    return path


@pytest.fixture(scope='module')
def planned(micromill, short_csv):
    result = plan(str(short_csv), micromill, feed=0.01)
    assert result.ok and result.status == PlanStatus.OK and result.reason == ''
    return result


def test_plan_result_is_exact_inside_the_limits_and_at_rest(planned, micromill):
    r = planned.plan
    assert r.max_position_deviation <= 1e-9 and r.max_orientation_deviation <= 1e-9
    assert set(r.peak_ratios) == set(micromill.axis_names)
    for name, ratios in r.peak_ratios.items():
        assert max(ratios.values()) <= 1.001, name
    ref = r.reference
    assert r.traversal_time == pytest.approx((len(ref) - 1) * micromill.control_period)
    assert r.traversal_time >= r.path.length / 0.01          # the process feed limit
    assert not ref.velocity[[0, -1]].any() and not ref.acceleration[[0, -1]].any()
    T = micromill.control_period
    jerk = np.abs(np.diff(ref.position, 3, axis=0)).max(axis=0) / T**3
    assert (jerk <= 1.001 * np.array([a.limits.jerk for a in micromill.axes])).all()


def test_plan_rejects_a_bad_feed(micromill):
    result = plan('circle_xy', micromill, feed=-1.0)
    assert result.status == PlanStatus.INVALID_INPUT and not result.ok
    assert 'feed must be a positive finite speed' in result.reason and result.plan is None
    with pytest.raises(PlanError, match='feed'):       # asking a failed result for its plan
        result.unwrap()


@pytest.mark.parametrize('what, expected', [('no_such_toolpath', 'not a built-in toolpath'),
                                            ('machine', 'unknown machine')])
def test_plan_reports_bad_inputs(micromill, what, expected):
    result = plan(what, micromill) if what != 'machine' else plan('circle_xy', 'no_such_machine')
    assert result.status == PlanStatus.INVALID_INPUT and expected in result.reason


def tip_arc(machine, shift=0.0, points=24):
    """Half circle of 1 mm radius from the home tool tip (+ shift in x), tool axis +z."""
    tip, _ = Kinematics.from_config(machine).forward(np.zeros(len(machine.axes)))
    th = np.linspace(0.0, math.pi, points)
    p = np.column_stack([tip[0] + shift + 1e-3 * (np.cos(th) - 1), tip[1] + 1e-3 * np.sin(th),
                         np.full(points, tip[2])])
    return toolpath.from_arrays(p, np.tile([0.0, 0.0, 1.0], (points, 1)))


def test_a_path_out_of_the_strokes_is_out_of_stroke_not_singular(micromill):
    # 0.2 m beside the home tool tip: x_c (stroke +-50 mm) would have to be at about -0.2 m;
    # the redundancy resolution used to end in numpy's "Singular matrix" here
    result = plan(tip_arc(micromill, shift=0.2), micromill, feed=0.01)
    assert result.status == PlanStatus.OUT_OF_STROKE
    assert result.reason.startswith('the path starts out of reach inside the strokes: x_c at -0.19')
    assert 'outside its stroke [-0.05, 0.05] m by 150 mm (point 0)' in result.reason     # 0.2 m - 50 mm
    assert 'ingular' not in result.reason


def straight(machine, length, points=24):
    """A straight line of `length` (m) in -x from the home tool tip, tool axis +z."""
    tip, _ = Kinematics.from_config(machine).forward(np.zeros(len(machine.axes)))
    p = np.column_stack([tip[0] - np.linspace(0.0, length, points), np.full(points, tip[1]), np.full(points, tip[2])])
    return toolpath.from_arrays(p, np.tile([0.0, 0.0, 1.0], (points, 1)))


@pytest.fixture
def no_long_planning(monkeypatch):
    """plan() must refuse before the spline fit and the redundancy resolution."""
    def never(*args, **kwargs):
        raise AssertionError('the long planning stages ran')
    monkeypatch.setattr(planner.ArcLengthPath, 'fit', never)
    monkeypatch.setattr(planner, 'resolve', never)


def test_a_path_leaving_the_strokes_midway_is_refused_at_its_first_point_out(micromill, no_long_planning):
    # 80 mm in -x, points 80/23 mm apart, c_f kept still: x_c (+-50 mm) carries the motion
    # (the fine x_f, 1/500 of its stroke, almost none: the solve weighs the axes by their
    # strokes squared); point 15 at 52.17 mm is the first beyond, by 2.17 mm
    only = RedundancySettings(active_axes=tuple(a for a in micromill.axis_names if a != 'c_f'))
    result = plan(straight(micromill, 0.08), micromill, feed=0.01, settings=only)
    assert result.status == PlanStatus.OUT_OF_STROKE
    assert result.reason == ('the path leaves the reach of the strokes at point 15: x_c at 0.0521737 m, '
                             'outside its stroke [-0.05, 0.05] m by 2.17 mm')


def test_a_tilt_beyond_the_table_is_refused_at_its_first_point(micromill, no_long_planning):
    # the tool axis tilted 0.1 rad about y: b_f would turn -0.1 rad, 91.3 mrad beyond its 0.5 deg
    cl = tip_arc(micromill)
    tilted = toolpath.from_arrays(cl.positions, np.tile([math.sin(0.1), 0.0, math.cos(0.1)], (len(cl), 1)))
    result = plan(tilted, micromill, feed=0.01)
    assert result.status == PlanStatus.OUT_OF_STROKE
    assert result.reason == ('the path starts out of reach inside the strokes: b_f at -0.1 rad, outside its '
                             'stroke [-0.00872665, 0.00872665] rad by 91.3 mrad (point 0)')


def test_a_pose_out_of_reach_between_the_samples_is_named_when_the_resolution_breaks_down(micromill):
    # 200 points 0.1 mm apart; point 100 (between the samples 98 and 101 of the quick check)
    # tilts the tool 2 deg: b_f would turn 2 deg, 1.5 deg = 26.2 mrad beyond its stroke
    tip, _ = Kinematics.from_config(micromill).forward(np.zeros(len(micromill.axes)))
    p = tip + np.outer(np.arange(200) * 1e-4, [1.0, 0.0, 0.0])
    o = np.tile([0.0, 0.0, 1.0], (200, 1))
    o[100] = [math.sin(math.radians(2)), 0.0, math.cos(math.radians(2))]
    result = plan(toolpath.from_arrays(p, o), micromill, feed=0.01)
    assert result.status == PlanStatus.OUT_OF_STROKE
    assert result.reason.startswith('the path leaves the reach of the strokes at point 100: b_f at -0.03490')
    assert result.reason.endswith('rad, outside its stroke [-0.00872665, 0.00872665] rad by 26.2 mrad')


def test_a_path_the_resolution_cannot_follow_to_a_stroke_end_names_the_points_and_the_axis(micromill):
    # 49.9 mm in -x: every pose is inside the strokes (x_c + x_f reach 50.1 mm), but the
    # stroke cost holds x_c off its end and the resolution breaks down ~0.5 mm before it
    result = plan(straight(micromill, 0.0499, points=40), micromill, feed=0.01)
    assert result.status == PlanStatus.OUT_OF_STROKE and 'ingular' not in result.reason
    assert result.reason.startswith('the redundancy resolution cannot keep the axes inside their strokes '
                                    'between points 38 and 39 (s = 49.')
    assert ': x_c at 0.049' in result.reason and 'from the end of its stroke [-0.05, 0.05] m' in result.reason


def test_points_closer_than_the_machine_resolves_are_refused(micromill, no_long_planning):
    # 10 nm apart: below the 20 nm of the table's sensors (CIRP section 2), the finest linear ones
    cl = toolpath.from_arrays(np.outer(np.arange(24) * 1e-8, [1.0, 0.0, 0.0]), np.tile([0.0, 0.0, 1.0], (24, 1)))
    result = plan(cl, micromill, feed=0.01)
    assert result.status == PlanStatus.INVALID_INPUT
    assert result.reason == ('points 0 and 1 are 1e-08 m apart (need >= 2e-08 m), the finest sensor resolution '
                             'of the linear axes of micromill_9axis')


def test_a_path_shorter_than_the_feed_grid_resolves_is_refused(micromill, no_long_planning):
    cl = toolpath.from_arrays(np.outer(np.arange(6) * 1e-7, [1.0, 0.0, 0.0]), np.tile([0.0, 0.0, 1.0], (6, 1)))
    result = plan(cl, micromill, feed=0.01)
    assert result.status == PlanStatus.INVALID_INPUT
    assert result.reason == 'the path is 5e-07 m long (need >= 1e-06 m for the feed optimization)'


def test_a_tool_tip_beyond_the_workspace_is_unreachable(micromill, no_long_planning):
    cl = tip_arc(micromill)
    p = cl.positions.copy()
    p[2] = [1e6, 0.0, 0.0]
    result = plan(toolpath.from_arrays(p, cl.axes), micromill, feed=0.01)
    assert result.status == PlanStatus.UNREACHABLE
    assert result.reason.startswith('point 2: tool tip (1e+06, 0, 0) m is beyond the workspace: 1e+06 m from the '
                                    'workpiece origin, where no tool tip of micromill_9axis is farther than 0.')


def test_a_start_reachable_only_in_another_configuration_says_so(micromill):
    # a helix of 60 mm radius starts 60 mm beside the c_f axis: x_c alone (+-50 mm) is 10 mm
    # short, the table turned by c_f reaches it; the planner starts from home with every axis
    # moved in proportion to its stroke, which keeps the table still
    result = plan(toolpath.helix(radius=0.06), micromill, feed=0.01)
    assert result.status == PlanStatus.OUT_OF_STROKE
    assert re.fullmatch(r'point 0 is reachable inside the strokes, but not in the start configuration the planner '
                        r'takes \(from home, each axis moved in proportion to its stroke\): x_c at -0\.060\d* m, '
                        r'outside its stroke \[-0\.05, 0\.05\] m by 10\.\d mm', result.reason), result.reason


def test_a_vertical_tool_on_the_tilting_table_machine_is_out_of_stroke(trt, no_long_planning):
    # trt_5axis holds the tool along the workpiece's y at home: +z needs a = -pi/2, 70.8 mrad
    # beyond its +-1.5 rad
    result = plan('circle_xy', trt, feed=0.01)
    assert result.status == PlanStatus.OUT_OF_STROKE
    assert result.reason == ('the path starts out of reach inside the strokes: a at -1.5708 rad, outside its '
                             'stroke [-1.5, 1.5] rad by 70.8 mrad (point 0)')


@pytest.mark.parametrize('machine_name', ['micromill_9axis', 'trt_5axis'])
def test_the_reach_radius_bounds_every_tool_tip_inside_the_strokes(machine_name, request):
    machine = request.getfixturevalue({'micromill_9axis': 'micromill', 'trt_5axis': 'trt'}[machine_name])
    kinematics = Kinematics.from_config(machine)
    radius = reach.reach_radius(kinematics, machine)
    rng = np.random.default_rng(7)
    lo = np.array([a.stroke[0] if a.stroke else -math.pi for a in machine.axes])
    hi = np.array([a.stroke[1] if a.stroke else math.pi for a in machine.axes])
    corners = np.array(np.meshgrid(*zip(lo, hi))).reshape(len(lo), -1).T      # every stroke end
    for q in np.vstack((corners, rng.uniform(lo, hi, (500, len(lo))))):
        assert np.linalg.norm(kinematics.forward(q)[0]) <= radius
    # a bound, not a blanket: within 3x the farthest tool tip found (x-y-z strokes of 0.1 m /
    # 0.6 m per axis)
    farthest = max(np.linalg.norm(kinematics.forward(q)[0]) for q in corners)
    assert radius <= 3 * farthest


def test_a_start_the_active_axes_cannot_reach_is_unreachable(micromill):
    # only x and y move: a path 1 mm above the home tool tip cannot be reached
    cl = tip_arc(micromill)
    lifted = toolpath.from_arrays(cl.positions + [0.0, 0.0, 1e-3], cl.axes)
    result = plan(lifted, micromill, feed=0.01,
                  settings=RedundancySettings(active_axes=('x_c', 'y_c', 'x_f', 'y_f')))
    assert result.status == PlanStatus.UNREACHABLE and 'cannot reach R(0)' in result.reason


def test_cli_plan_writes_references_and_json(short_csv, tmp_path, capsys, micromill):
    out = tmp_path / 'out'
    assert cli.main(['plan', str(short_csv), '--out', str(out), '--json']) == 0
    summary = json.loads(capsys.readouterr().out)
    for key in ('traversal_time', 'planning_time', 'max_position_deviation',
                'max_orientation_deviation', 'peak_ratios', 'peak_feed_ratio'):
        assert key in summary
    assert list(summary['peak_ratios']) == list(micromill.axis_names)
    assert 0.5 < summary['peak_feed_ratio'] <= 1.0 + 1e-12
    lines = (out / 'references.csv').read_text().splitlines()
    assert lines[0] == 'time,' + ','.join(micromill.axis_names)
    table = np.loadtxt(out / 'references.csv', delimiter=',', skiprows=1)
    assert table[0, 0] == 0.0
    assert table[-1, 0] == pytest.approx(summary['traversal_time'])


@pytest.mark.parametrize('content', [None, 'px,py,pz,oi,oj,ok\n0,0,0,0,0,1\nx,1,2,3,4,5\n'])
def test_cli_plan_bad_path_exits_2_with_one_line(tmp_path, capsys, content):
    if content is None:
        target = 'no_such_toolpath'
    else:
        target = tmp_path / 'bad.csv'
        target.write_text(content)
    assert cli.main(['plan', str(target), '--out', str(tmp_path / 'o')]) == 2
    captured = capsys.readouterr()
    assert captured.out == ''
    assert len(captured.err.strip().splitlines()) == 1


def test_local_re_solve_keeps_the_optimizers_time_and_every_limit(micromill):
    # circle_xy's start-up transient (fine axes moving into the nullspace optimum) is finer
    # than the feed grid: the sampled jerk first exceeds the limits 2.6x in the first and
    # last millimetre only. The limits lowered there and the feed LP re-solved around them
    # (sampling.resolve_rule), the final time stays within 2 % of the optimizer's grid time
    # (the earlier global scale gave 1.49x).
    r = plan('circle_xy', micromill, feed=0.01).unwrap()
    assert r.traversal_time <= 1.02 * r.feed.duration()
    assert r.sampling.feed_scale == pytest.approx(1.0, abs=1e-3)    # no global fallback
    T = micromill.control_period
    ref = r.reference
    held = np.vstack([np.repeat(ref.position[:1], 3, 0), ref.position, np.repeat(ref.position[-1:], 3, 0)])
    for i, axis in enumerate(micromill.axes):
        if axis.stroke:
            assert axis.stroke[0] <= ref.position[:, i].min() <= ref.position[:, i].max() <= axis.stroke[1]
        for k, limit in ((1, axis.limits.velocity), (2, axis.limits.acceleration), (3, axis.limits.jerk)):
            assert np.abs(np.diff(held[:, i], k)).max() / T**k <= 1.001 * limit, (axis.name, k)
    assert r.max_position_deviation <= 1e-9 and r.max_orientation_deviation <= 1e-9
