"""The trajectory session (trajectory/session.py) without ROS: states, refusals with their
reasons, goal bookkeeping, feed hold / resume / stop, faults, and what is handed to the
node to publish, in order."""
import math

import numpy as np
import pytest

from trajectory import toolpath
from trajectory.moves import AxisState, move_to
from trajectory.session import Answer, Session, State, plan_path

CHUNK, LOOKAHEAD = 500, 1000
HERE = [1e-3, -0.5e-3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]


class Recorder:
    """trajectory.session.Outputs that keeps everything: rows by step (last one wins, as a
    servo reads a re-sent stream), and the session's state at every status publication."""

    def __init__(self):
        self.by_step, self.chunks, self.states, self.logs, self.warnings = {}, [], [], [], []
        self.session = None

    def rows(self, first, positions, velocities, accelerations):
        self.chunks.append(first)
        for k, p in enumerate(positions):
            self.by_step[first + k] = p

    def status(self):
        self.states.append(self.session.status_values()['state'])

    def log(self, text):
        self.logs.append(text)

    def warn(self, text):
        self.warnings.append(text)


@pytest.fixture
def out():
    return Recorder()


def session_of(machine, out, start_step=None):
    session = Session(machine, out, CHUNK, LOOKAHEAD)
    out.session = session
    if start_step is not None:
        session.start_streaming(HERE, start_step)
    return session


def run_until_idle(session, limit=10**6):
    """Advance the sim time a chunk at a time until the session is idle again."""
    step = session.step
    while session.state != State.IDLE:
        step += CHUNK
        session.tick(step)
        assert step < limit, 'the motion never ended'
    return step


def streamed(out):
    steps = sorted(out.by_step)
    assert steps == list(range(steps[0], steps[-1] + 1)), 'the stream has a gap'
    return steps[0], np.array([out.by_step[k] for k in steps])


def test_before_the_first_state_goals_are_refused_and_nothing_streams(micromill, out):
    session = session_of(micromill, out)
    assert not session.accept_joint_goal(['x_c'], [[2e-3]], [0.0])
    assert session.home() == Answer(False, 'home: the machine state is not known yet (no /joint_states)')
    values = session.status_values()
    assert values['state'] == 'idle' and values['rejected_goals'] == 2 and values['streamed_to_step'] == ''
    assert values['progress'] == '0' and values['feed_override'] == '1'
    assert values['last_rejection'] == 'home: the machine state is not known yet (no /joint_states)'
    assert out.by_step == {} and out.states == ['idle', 'idle']
    assert out.warnings[0] == 'rejected joint goal: the machine state is not known yet (no /joint_states)'


def test_the_first_state_is_held_lookahead_rows_ahead(micromill, out):
    session = session_of(micromill, out, start_step=100)
    assert out.chunks == [100, 600] and out.states == ['idle']      # rows 100 .. 1099, then the status
    first, rows = streamed(out)
    assert first == 100 and len(rows) == 1000 and (rows == HERE).all()
    session.tick(700)                                                # keeps 1000 rows ahead of the sim
    assert out.chunks == [100, 600, 1100, 1600]
    session.tick(650)                                                # time never runs back
    assert session.step == 700 and out.chunks == [100, 600, 1100, 1600]


KEYS = ['state', 'step', 'progress', 'motion', 'motion_start_step', 'motion_end_step', 'streamed_to_step',
        'feed_override', 'feed_override_setting', 'fault', 'rejected_goals', 'last_rejection']


def test_a_joint_goal_runs_from_the_first_row_not_streamed_and_ends_idle(micromill, out):
    session = session_of(micromill, out, start_step=0)
    assert session.accept_joint_goal(['x_c'], [[3e-3]], [0.0])
    move = move_to(micromill, [3e-3] + HERE[1:], AxisState.at_rest(HERE))
    values = session.status_values()
    assert list(values) == KEYS
    assert values['state'] == 'running' and values['motion'] == 'joint goal (1 points)'
    assert values['motion_start_step'] == 1000 and values['motion_end_step'] == ''
    assert out.logs == [f'joint goal (1 points): {len(move)} steps from step 1000', 'state: running']
    # one motion at a time
    assert not session.accept_joint_goal(['y_c'], [[0.0]], [0.0])
    assert session.rejections.last == 'joint goal: busy (running); one motion at a time'
    end = run_until_idle(session)
    assert session.status_values()['motion_end_step'] == 1000 + len(move) - 1 <= end
    assert out.states[:2] == ['idle', 'running'] and out.states[-1] == 'idle'   # streaming, goal, end
    first, rows = streamed(out)
    np.testing.assert_array_equal(rows[1000:1000 + len(move)], move.position)
    assert (rows[1000 + len(move):] == move.position[-1]).all()       # then the last position is held
    assert session.status_values()['progress'] == '1.0000'


@pytest.mark.parametrize('names, points, times, reason', [
    (['x_c', 'q_z'], [[1e-3, 0.0]], [0.0], 'unknown joints q_z'),
    (['x_f'], [[0.5e-3]], [0.0], 'outside its stroke'),
    (['x_c'], [[1e-3], [2e-3]], [0.2, 0.1], 'strictly increasing'),
    (['x_c'], [], [], 'no points'),
])
def test_bad_joint_goals_are_refused_with_the_reason_and_nothing_moves(micromill, out, names, points, times,
                                                                       reason):
    session = session_of(micromill, out, start_step=0)
    assert not session.accept_joint_goal(names, points, times)
    assert session.state == State.IDLE and session.rejections.count == 1
    assert session.rejections.last.startswith('joint goal: ') and reason in session.rejections.last
    session.tick(5000)
    assert (streamed(out)[1] == HERE).all()


def test_feed_override_is_a_fraction_and_sets_the_next_motions_feed(micromill, out):
    session = session_of(micromill, out, start_step=0)
    for bad in (1.5, -0.1, math.nan, math.inf):
        assert not session.set_feed_override(bad)
        assert session.rejections.last == f'feed override: {bad!r} is not a fraction within [0, 1]'
    assert session.rejections.count == 4 and session.override_setting == 1.0
    assert session.set_feed_override(0.5)
    assert session.status_values()['feed_override_setting'] == 0.5
    full = len(move_to(micromill, [3e-3] + HERE[1:], AxisState.at_rest(HERE)))
    session.accept_joint_goal(['x_c'], [[3e-3]], [0.0])
    run_until_idle(session)
    values = session.status_values()
    took = values['motion_end_step'] - values['motion_start_step']
    assert abs(took - 2 * (full - 1)) <= 2                          # half the feed, twice the time


def test_hold_resume_and_stop(micromill, out):
    session = session_of(micromill, out, start_step=0)
    for command in (session.hold, session.resume, session.stop):
        assert command() == Answer(False, 'not applicable while idle')
    session.set_feed_override(0.25)                                   # a long motion
    session.accept_joint_goal(['x_c'], [[-40e-3]], [0.0])
    session.tick(2000)
    assert session.hold() == Answer(True, 'feed 0 from step 2500')    # a chunk beyond the newest step
    assert session.state == State.HOLDING
    for step in range(2500, 40000, CHUNK):                            # the hold keeps the motion
        session.tick(step)
    assert session.state == State.HOLDING and session.status_values()['feed_override'] == '0.0000'
    _, rows = streamed(out)
    still = rows[-1]
    assert -40e-3 < still[0] < HERE[0] and (rows[-5000:] == still).all()
    assert session.home().message == 'home: busy (holding); one motion at a time'
    assert session.resume().message == 'feed 0.25 from step 40000' and session.state == State.RUNNING
    session.tick(40500)
    assert session.stop().success and session.state == State.HOLDING
    assert session.resume() == Answer(False, 'not applicable while holding')   # a stop is not resumed
    run_until_idle(session)
    _, rows = streamed(out)
    assert -40e-3 < rows[-1][0] < still[0] and (rows[-1000:] == rows[-1]).all()
    assert out.states.count('holding') >= 3 and out.states[-1] == 'idle'


def test_home_moves_to_the_machine_home(micromill, out):
    session = session_of(micromill, out, start_step=0)
    expected = len(move_to(micromill, micromill.home, AxisState.at_rest(HERE)))
    assert session.home() == Answer(True, f'homing in {expected} steps')
    assert session.status_values()['motion'] == 'home'
    run_until_idle(session)
    np.testing.assert_allclose(streamed(out)[1][-1], micromill.home, rtol=0, atol=1e-15)


def test_a_planned_path_starts_after_an_approach_and_a_failed_one_is_refused(micromill, out):
    session = session_of(micromill, out, start_step=0)
    assert session.may_accept('path')
    session.planning('path of 24 points')
    assert session.state == State.PLANNING and session.awaiting_plan and out.states[-1] == 'planning'
    assert not session.accept_joint_goal(['x_c'], [[2e-3]], [0.0])
    assert session.rejections.last == 'joint goal: busy (planning); one motion at a time'
    session.path_planned(None, 'the path is out of reach inside the strokes')
    assert session.state == State.IDLE and not session.awaiting_plan
    assert session.rejections.last == 'path: planning failed: the path is out of reach inside the strokes'
    assert out.states[-2:] == ['idle', 'idle']                         # the state, then the refusal

    # "the path": a move from A to B; the session approaches A from where the stream holds
    a, b = [2e-3] + HERE[1:], [2e-3, 1e-3] + HERE[2:]
    path = move_to(micromill, b, AxisState.at_rest(a))
    approach = move_to(micromill, a, AxisState.at_rest(HERE))
    session.planning('path of 24 points')
    session.tick(300)
    session.path_planned(path)
    assert session.state == State.RUNNING and session.status_values()['motion'] == 'path of 24 points'
    start = session.status_values()['motion_start_step']
    assert start == 1500                                 # the first row not yet streamed (300 + lookahead)
    run_until_idle(session)
    _, rows = streamed(out)
    np.testing.assert_array_equal(rows[start:start + len(approach)], approach.position)
    np.testing.assert_array_equal(rows[start + len(approach) - 1:start + len(approach) + len(path) - 1],
                                  path.position)
    # a plan that arrives when none is wanted is dropped
    session.path_planned(path)
    assert session.state == State.IDLE


def test_a_fault_drops_the_motion_holds_the_fault_step_and_refuses_until_reset(micromill, out):
    session = session_of(micromill, out, start_step=0)
    session.accept_joint_goal(['x_c'], [[-40e-3]], [0.0])
    session.tick(3000)
    session.machine_status(True, 'missing command for x_c', '2500')
    assert session.state == State.FAULT and session.faulted and session.fault == 'missing command for x_c'
    values = session.status_values()
    assert values['state'] == 'fault' and values['fault'] == 'missing command for x_c' and values['motion'] == ''
    _, rows = streamed(out)
    assert (rows[2501:] == rows[2501]).all() and rows[2501][0] != HERE[0]    # held from the fault step on
    session.machine_status(True, 'another', '2600')                     # already faulted: nothing new
    assert session.fault == 'missing command for x_c'
    assert not session.accept_joint_goal(['x_c'], [[1e-3]], [0.0])
    assert session.rejections.last == ('joint goal: machine is faulted (missing command for x_c); '
                                      'reset hw_sim first')
    assert session.hold() == Answer(False, 'not applicable while fault')
    session.machine_status(False)
    assert session.state == State.IDLE and session.fault == ''
    assert out.logs[-2:] == ['state: fault', 'state: idle']
    assert session.accept_joint_goal(['x_c'], [[rows[2501][0] + 1e-3]], [0.0])


def test_a_fault_while_planning_drops_the_plan(micromill, out):
    session = session_of(micromill, out, start_step=0)
    session.planning('path of 24 points')
    session.machine_status(True, 'estop', '')
    assert session.state == State.FAULT and not session.awaiting_plan
    session.path_planned(move_to(micromill, HERE, AxisState.at_rest(HERE)))
    assert session.state == State.FAULT


def test_plan_path_reports_why_a_path_cannot_be_planned(micromill, micromill_kin):
    tip, _ = micromill_kin.forward(np.zeros(len(micromill.axes)))
    th = np.linspace(0.0, math.pi, 24)
    p = np.column_stack([tip[0] + 0.2 + 1e-3 * (np.cos(th) - 1), tip[1] + 1e-3 * np.sin(th), np.full(24, tip[2])])
    reference, reason = plan_path(micromill, toolpath.from_arrays(p, np.tile([0.0, 0.0, 1.0], (24, 1))), 0.01)
    assert reference is None and 'x_c at -0.19' in reason and 'ingular' not in reason
