"""Item 7 of [6/8]: contour-error estimates that never jump. At path starts, joins (approach ->
path, path -> stop), reversals, corners and ends every estimate is either within its stated
bound of the closest-point truth (machine_ctrl/contour/truth.py) or marked invalid
(machine_ctrl/contour/validity.py, README "Contour error", "Validity"); the invalid steps are
few and sit at the joins. ROS-free; the node over real DDS: test_contour_node.py."""
import numpy as np
import pytest

from machine_ctrl.contour.estimation import ESTIMATORS, OrientationEstimator, ToolTipEstimator, ToolTrajectory
from machine_ctrl.contour.truth import true_orientation_errors, true_tool_tip_errors
from machine_ctrl.contour.validity import BOUND_ABS, Tolerance, machine_tolerances

PERIOD = 1e-3


# --- a synthetic path: stops, a reversal, a corner after a long rest, an arc, an end --------------

def quintic(length, duration):
    """Rest-to-rest arc length s(t) over `duration`: (s, s', s'') at t."""
    def law(t):
        u = np.clip(t / duration, 0.0, 1.0)
        return (length * (10 * u ** 3 - 15 * u ** 4 + 6 * u ** 5),
                length * (30 * u ** 2 - 60 * u ** 3 + 30 * u ** 4) / duration,
                length * (60 * u - 180 * u ** 2 + 120 * u ** 3) / duration ** 2)
    return law


def line(start, direction, length, duration):
    start, direction = np.asarray(start, float), np.asarray(direction, float) / np.linalg.norm(direction)
    law = quintic(length, duration)

    def at(t):
        s, v, a = law(t)
        return start + s[:, None] * direction, v[:, None] * direction, a[:, None] * direction
    return at, duration, start + length * direction


def arc(center, radius, angle0, sweep, duration):
    center = np.asarray(center, float)
    law = quintic(abs(sweep) * radius, duration)
    sign = np.sign(sweep)

    def at(t):
        s, v, a = law(t)
        th = angle0 + sign * s / radius
        c, n = np.column_stack((np.cos(th), np.sin(th), 0 * th)), np.column_stack((-np.sin(th), np.cos(th), 0 * th))
        return (center + radius * c, sign * v[:, None] * n,
                sign * a[:, None] * n - (v * v / radius)[:, None] * c)
    return at, duration, center + radius * np.array([np.cos(angle0 + sweep), np.sin(angle0 + sweep), 0.0])


def rest(point, duration):
    point = np.asarray(point, float)

    def at(t):
        z = np.zeros((len(t), 3))
        return point + z, z, z
    return at, duration, point


def synthetic_path():
    """(segments, boundaries in steps): rest, +x 10 mm, a 20 ms stop (inside the 50-step
    horizon), back 5 mm along -x (a reversal), a 200 ms stop, +y 5 mm (a 90 deg corner after a
    rest longer than the horizon), a quarter arc of 4 mm radius, the end at rest."""
    segments, here = [], np.zeros(3)
    for make in (lambda p: rest(p, 0.05), lambda p: line(p, [1, 0, 0], 0.010, 1.0), lambda p: rest(p, 0.02),
                 lambda p: line(p, [-1, 0, 0], 0.005, 0.6), lambda p: rest(p, 0.2),
                 lambda p: line(p, [0, 1, 0], 0.005, 0.6),
                 lambda p: arc(p + [-0.004, 0.0, 0.0], 0.004, 0.0, np.pi / 2, 0.8), lambda p: rest(p, 0.3)):
        segment = make(here)
        segments.append(segment)
        here = segment[2]
    return segments


def evaluate(segments, t):
    """P, V, A of the piecewise path at times t (s)."""
    out = [np.zeros((len(t), 3)) for _ in range(3)]
    begin = 0.0
    for i, (at, duration, _) in enumerate(segments):
        last = i == len(segments) - 1
        mask = (t >= begin) & ((t < begin + duration) | last)
        if mask.any():
            for o, x in zip(out, at(np.clip(t[mask] - begin, 0.0, duration))):
                o[mask] = x
        begin += duration
    return out


@pytest.fixture(scope='module')
def synthetic():
    segments = synthetic_path()
    total = sum(s[1] for s in segments)
    n = int(round(total / PERIOD))
    t = np.arange(n) * PERIOD
    p, v, a = evaluate(segments, t)
    trajectory = ToolTrajectory(PERIOD)
    o = np.tile([0.0, 0.0, 1.0], (n, 1))
    trajectory.add(0, p, v, a, o, np.zeros((n, 3)))
    # the actual tool: 4 ms behind, 2 um off the plane, 1 um aside, 0.2 um of noise
    rng = np.random.default_rng(7)
    lagging = evaluate(segments, np.maximum(t - 0.004, 0.0))[0]
    actual = lagging + [1e-6, -1e-6, 2e-6] + 0.2e-6 * rng.standard_normal((n, 3))
    joins = np.round(np.cumsum([0.0] + [s[1] for s in segments]) / PERIOD).astype(int)
    return trajectory, actual, true_tool_tip_errors(trajectory, actual), joins


def estimates(trajectory, actual, method, tolerance=Tolerance(), reasons=False):
    estimator = ToolTipEstimator(method, tolerance)
    out = [estimator.estimate(trajectory, k, pk) for k, pk in enumerate(actual.tolist())]
    arrays = (np.array([e.vector for e in out]), np.array([e.check.bound for e in out]),
              np.array([e.check.valid for e in out]))
    return arrays + (np.array([e.check.reason for e in out]),) if reasons else arrays


def assert_within_bound_or_invalid(vector, bound, valid, truth):
    deviation = np.linalg.norm(vector - truth, axis=1)
    outside = np.flatnonzero(valid & (deviation > bound))
    assert not len(outside), [(int(k), deviation[k], bound[k]) for k in outside[:5]]
    return deviation


def near(steps, joins, before, after):
    """The steps that lie within [join - before, join + after] of some join."""
    steps = np.asarray(steps)
    return np.array([any(j - before <= k <= j + after for j in joins) for k in steps], bool)


@pytest.mark.parametrize('method', ESTIMATORS)
def test_synthetic_joins_stops_reversal_corner(synthetic, method):
    trajectory, actual, truth, joins = synthetic
    vector, bound, valid, reason = estimates(trajectory, actual, method, reasons=True)
    deviation = assert_within_bound_or_invalid(vector, bound, valid, truth)
    # invalid for a join, a stop, the reversal or the corner: from the last 50 ms of a motion to
    # 80 ms after it starts again (the window of a few um of arc around the closest point takes
    # that long to leave the rest point of a quintic start; the lag is 4 ms); few: compensated
    # 156 steps for the 7 joins (Theta over the window: 'turn'; the path ahead of a rest not yet
    # in the 200 steps looked at: 'horizon')
    at_joins = np.flatnonzero(~valid & (reason != 'bound'))
    assert near(at_joins, joins, 50, 80).all(), at_joins[~near(at_joins, joins, 50, 80)]
    assert len(at_joins) <= 170, len(at_joins)
    # basic and shifted are also invalid along the arc, where their first-order error kappa
    # lag^2 / 2 (0.45 um at 60 um of lag on 4 mm) is too close to the 25 % of the 2.3 um errors
    # ('bound'), and only in its fast middle: its first-order bound kappa r (r + d) (r the 4 ms
    # lag of arc, d ~2.2 um; validity.py) passes the 0.55 um tolerance at r ~46 um, 11.4 mm/s of
    # the quintic's 14.7 mm/s peak, the middle 34 % of the arc's 800 steps; the full bound (the
    # turning over its window, 1 / (1 - Theta ...)) is ~1.5x that, the middle half (basic 372
    # steps, shifted 397). Held to the middle 60 %, where the speed is over 6 mm/s (at 24 um of
    # lag the first-order bound, 0.16 um, is a third of the tolerance), and to 55 % of the arc.
    # Every other step is valid: the estimates cover the path but for its joins and that arc.
    steps = np.arange(len(valid))
    arc_start, arc_end = joins[6], joins[7]
    middle = (steps >= arc_start + 0.2 * (arc_end - arc_start)) & (steps <= arc_end - 0.2 * (arc_end - arc_start))
    at_bound = ~valid & (reason == 'bound')
    if method == 'compensated':
        assert not at_bound.any()
        assert valid[~near(steps, joins, 50, 80)].all()
    else:
        assert not (at_bound & ~middle).any(), steps[at_bound & ~middle]
        assert np.count_nonzero(at_bound) <= 0.55 * (arc_end - arc_start), np.count_nonzero(at_bound)
        assert valid[~near(steps, joins, 50, 80) & ~middle].all()
    # valid steps are useful: compensated within 0.1 um of the 2.3 um errors, every one within
    # the tolerance, 25 % of the estimate
    assert deviation[valid].max() < 0.1e-6 or method != 'compensated'
    assert (deviation[valid] <= 0.25 * np.linalg.norm(vector[valid], axis=1)).all()
    # and the marking is needed: at the joins the estimates are off by half the error
    assert deviation[at_joins].max() > 0.5 * np.linalg.norm(truth[at_joins], axis=1).min()


def test_the_corner_after_a_long_rest_is_seen_through_the_memory_of_the_rest(synthetic):
    """The +y segment starts 200 steps (> the 50-step horizon) after the reversal ended: the
    first steps along +y must see the -x segment behind the corner (PathMemory), and are
    invalid while the truth may lie on it."""
    trajectory, actual, truth, joins = synthetic
    vector, bound, valid = estimates(trajectory, actual, 'compensated')
    corner = joins[5]                                   # +y starts here
    assert not valid[corner + 1:corner + 8].any()
    assert valid[corner + 60:corner + 200].all()
    # the 200 ms rest before it, at the corner: valid while the tool is behind the corner on the
    # arriving side (corner_check), but for its first 33 steps, while the rows looked at (200
    # ahead) hold too little of the path leaving it: invalid ('horizon')
    assert not valid[corner - 199:corner - 166].any() and valid[corner - 166:corner + 1].all()


def test_holding_on_a_straight_path_stays_valid():
    """A stop and restart in the same direction is no corner: the turning across the rest is
    nil, and the steps through it stay valid (and within the bound)."""
    segments = [rest(np.zeros(3), 0.05)]
    segments.append(line(segments[-1][2], [1, 1, 0], 0.004, 0.5))
    segments.append(rest(segments[-1][2], 0.1))
    segments.append(line(segments[-1][2], [1, 1, 0], 0.004, 0.5))
    segments.append(rest(segments[-1][2], 0.1))
    n = int(round(sum(s[1] for s in segments) / PERIOD))
    t = np.arange(n) * PERIOD
    p, v, a = evaluate(segments, t)
    trajectory = ToolTrajectory(PERIOD)
    trajectory.add(0, p, v, a, np.tile([0.0, 0.0, 1.0], (n, 1)), np.zeros((n, 3)))
    actual = evaluate(segments, np.maximum(t - 0.004, 0.0))[0] + [0.0, 0.0, 2e-6]
    truth = true_tool_tip_errors(trajectory, actual)
    for method in ESTIMATORS:
        vector, bound, valid = estimates(trajectory, actual, method)
        assert_within_bound_or_invalid(vector, bound, valid, truth)
        assert valid.all(), np.flatnonzero(~valid)


def test_chunks_and_dropped_rows_give_what_the_whole_trajectory_gives(synthetic):
    """The node's trajectory (chunks of 97 rows, rows dropped `horizon` + 2 steps behind) and
    the offline one (all rows at once) give the same estimates and bounds, bit for bit."""
    whole, actual, _, _ = synthetic
    live = ToolTrajectory(PERIOD)
    rows = whole.rows
    offline, online = ToolTipEstimator('compensated'), ToolTipEstimator('compensated')
    sent = 0
    for k in range(len(actual)):
        while sent < min(len(actual), k + 300):
            live.add(sent, *rows[:, sent:sent + 97])
            sent += 97
        live.drop_before(k - live.horizon - 2)
        a, b = offline.estimate(whole, k, actual[k].tolist()), online.estimate(live, k, actual[k].tolist())
        assert (a.vector, a.check) == (b.vector, b.check), k
    for g_whole, g_live in zip(whole.geometry, live.geometry):
        held = slice(live.first, live.end)
        assert np.array_equal(g_whole.s[held], g_live.s) and np.array_equal(g_whole.phi[held], g_live.phi)


def test_bound_on_a_circle_is_a_bound_and_not_far_above_the_error():
    """Basic estimator on a circle with the actual point lagging: the error is kappa r^2/2 (+ a
    little), the bound about kappa r (r + d) / ... : above it, within ~10x."""
    from test_contour import circle_trajectory, lagging_points, R
    trajectory, th = circle_trajectory()
    actual = lagging_points(th, 0.004, 20e-6)
    truth = true_tool_tip_errors(trajectory, actual)
    vector, bound, _ = estimates(trajectory, actual, 'basic', Tolerance(1e-15, 0.0))   # the tightest bound
    k = slice(300, 1700)
    deviation = np.linalg.norm(vector - truth, axis=1)[k]
    assert (deviation <= bound[k]).all()
    lag = R * 0.004
    assert deviation.min() > 0.5 * lag ** 2 / (2 * R)
    assert bound[k].max() < 12 * deviation.max()


# --- the trt_5axis Eq. (35) run and the micromill helix with its approach (the issue's run) ----

def test_trt_eq35_run(trt, trt_kin):
    from hw_sim.offline import run
    from trajectory.sencer_path import sencer_reference
    reference = sencer_reference(trt)
    record = run(trt, reference)
    trajectory = ToolTrajectory.from_reference(trt_kin, reference)
    poses = [trt_kin.forward(q) for q in record.measured]
    p, o = np.array([x[0] for x in poses]), np.array([x[1] for x in poses])
    truth = true_tool_tip_errors(trajectory, p)
    tip_tolerance, axis_tolerance = machine_tolerances(trt)
    motion = np.flatnonzero(np.linalg.norm(trajectory.rows[1], axis=1) > 0)
    joins = [motion[0], motion[-1]]                     # the start and the final stop
    end = trajectory.rows[0, motion[-1] + 1]            # the final rest point, and the direction arriving there
    arriving = trajectory.rows[1, motion[-1]] / np.linalg.norm(trajectory.rows[1, motion[-1]])
    beyond = motion[(p[motion] - end) @ arriving > 0.0]     # moving steps with the tool past the path's end
    assert len(beyond) >= 10
    for method in ESTIMATORS:
        vector, bound, valid = estimates(trajectory, p, method, tip_tolerance)
        deviation = assert_within_bound_or_invalid(vector, bound, valid, truth)
        invalid = np.flatnonzero(~valid)
        assert len(invalid) <= 20 and near(invalid, joins, 20, 20).all(), invalid
        assert deviation[valid].max() < 1e-6
        # past the end the estimate is the distance to the end point (validity.beyond_end): the truth
        # there, where every frame's line was 12 um off before
        assert valid[beyond].all() and deviation[beyond].max() < 1e-9
        np.testing.assert_allclose(vector[beyond], end - p[beyond], rtol=0, atol=1e-15)
    estimator = OrientationEstimator(axis_tolerance)
    out = [estimator.update(trajectory, k, ok) for k, ok in enumerate(o.tolist())]
    assert_within_bound_or_invalid(np.array([e.vector for e in out]), np.array([e.check.bound for e in out]),
                                   np.array([e.check.valid for e in out]), true_orientation_errors(trajectory, o))


@pytest.fixture(scope='module')
def helix_with_approach(micromill, micromill_kin):
    """The issue's run: the micromill at rest at home, the approach move to the helix (Ruckig,
    as the trajectory session plays it), the helix, the final rest."""
    from hw_sim.offline import run
    from machine_ctrl.model.reference import Reference
    from trajectory import moves
    from trajectory.planner import plan
    path = plan('helix', micromill).unwrap().reference
    home = np.array(micromill.home, float)
    approach = moves.move_to(micromill, path.position[0], moves.AxisState.at_rest(home))

    def held(point, steps):
        zeros = np.zeros((steps, len(point)))
        return Reference(path.axis_names, path.period, np.tile(point, (steps, 1)), zeros, zeros)
    reference = moves.concatenate([held(home, 200), approach, path, held(path.position[-1], 400)])
    record = run(micromill, reference)
    trajectory = ToolTrajectory.from_reference(micromill_kin, reference)
    poses = [micromill_kin.forward(q) for q in record.measured]
    p, o = np.array([x[0] for x in poses]), np.array([x[1] for x in poses])
    join = 200 + len(approach) - 1
    return trajectory, p, o, [200, join, join + len(path) - 1]


def test_helix_with_approach_the_issue_run(micromill, helix_with_approach):
    """Before: compensated estimates up to 483 um off at the approach -> helix join (true 0.25 um)
    and 11 steps off by more than 1 um. Now those are invalid; every valid one is within its
    bound; the invalid ones sit at the start of the approach, the join and the end of the helix."""
    trajectory, p, o, joins = helix_with_approach
    truth = true_tool_tip_errors(trajectory, p)
    tip_tolerance, axis_tolerance = machine_tolerances(micromill)
    vector, bound, valid = estimates(trajectory, p, 'compensated', tip_tolerance)
    deviation = assert_within_bound_or_invalid(vector, bound, valid, truth)
    assert deviation.max() > 400e-6                      # the jump is there ...
    assert not valid[deviation > 1e-6].any()             # ... and marked
    assert deviation[valid].max() < 1e-9 and np.median(bound[valid]) < 1e-9
    invalid = np.flatnonzero(~valid)
    # the rest before the approach and its first 50 steps (the approach starts by curling
    # 0.7 rad within 2 um, more than the tool wanders at rest), 120 steps around the join, the
    # last 50 of the path
    assert near(invalid, joins, 200, 120).all(), invalid[~near(invalid, joins, 200, 120)]
    assert len(invalid) < 0.005 * len(p), len(invalid)
    estimator = OrientationEstimator(axis_tolerance)
    out = [estimator.update(trajectory, k, ok) for k, ok in enumerate(o.tolist())]
    valid_o = np.array([e.check.valid for e in out])
    assert_within_bound_or_invalid(np.array([e.vector for e in out]), np.array([e.check.bound for e in out]),
                                   valid_o, true_orientation_errors(trajectory, o))
    assert np.count_nonzero(~valid_o) < 0.01 * len(o)


def test_tolerances_of_the_machines(micromill, trt):
    tip, axis = machine_tolerances(micromill)
    assert (tip.absolute, axis.absolute) == (10e-9, 0.3e-6)
    assert machine_tolerances(trt)[0].absolute == pytest.approx(1.45e-6)
    assert Tolerance()(1e-9) == BOUND_ABS and Tolerance()(1e-3) == 0.25e-3


@pytest.mark.parametrize('method', ESTIMATORS)
def test_a_tool_past_the_paths_end_is_estimated_by_the_end_point_where_it_is_certainly_the_closest(method):
    """[8/8] part 4 (validity.beyond_end): a quarter arc of 0.5 mm radius ending at rest along
    +y, the tool 4 ms ahead of the reference and further along +y, so in the last steps of
    motion it is past the end. 10 um further and 1 um off the path, the end point is certainly
    the closest point: those steps are valid and their estimate is the truth (within 1 nm; no
    frame's line can give it). 0.2 um further and 10 um inside the arc, the arc turns towards
    the tool within the window by more than the rule allows (n sin Theta > s cos Theta: 10 um x
    ~0.06 rad against 0.2 um): the end point is not certainly the closest (on a circle it still
    is; the rule is a sufficient one), and those steps stay marked invalid ('end'). Every valid
    step is within its bound of the closest-point truth."""
    segments = [rest([0.0, -0.0005, 0.0], 0.05), arc([0.0, 0.0, 0.0], 0.0005, -np.pi / 2, np.pi / 2, 0.8),
                rest([0.0005, 0.0, 0.0], 0.2)]
    n = int(round(sum(s[1] for s in segments) / PERIOD))
    t = np.arange(n) * PERIOD
    p, v, a = evaluate(segments, t)
    trajectory = ToolTrajectory(PERIOD)
    trajectory.add(0, p, v, a, np.tile([0.0, 0.0, 1.0], (n, 1)), np.zeros((n, 3)))
    leading = evaluate(segments, t + 0.004)[0]
    moving = np.flatnonzero(np.linalg.norm(v, axis=1) > 0)
    end = p[-1]
    for offset, expect_valid in (([0.0, 10e-6, 1e-6], True), ([-10e-6, 0.2e-6, 0.0], False)):
        actual = leading + offset
        beyond = moving[actual[moving, 1] > end[1]]           # past the end: its direction there is +y
        assert len(beyond) >= 3
        truth = true_tool_tip_errors(trajectory, actual)
        vector, bound, valid, reason = estimates(trajectory, actual, method, Tolerance(), reasons=True)
        deviation = assert_within_bound_or_invalid(vector, bound, valid, truth)
        if expect_valid:
            assert valid[beyond].all() and deviation[beyond].max() < 1e-9
            np.testing.assert_allclose(vector[beyond], end - actual[beyond], rtol=0, atol=1e-15)
        else:
            assert not valid[beyond].any() and (reason[beyond] == 'end').all(), reason[beyond]
