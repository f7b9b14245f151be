"""The trajectory session (trajectory/session.py) without ROS: states, refusals with their
reasons, goal bookkeeping, feed hold / resume / stop, faults, and what is handed to the
node to publish, in order."""
import functools
import math

import numpy as np
import pytest
from limit_checks import assert_within_limits

from machine_ctrl import contract
from trajectory import toolpath
from trajectory.moves import AxisState, move_to
from trajectory.session import Answer, Session, State, plan_path

NO_STATE = f'the machine state is not known yet (no {contract.JOINT_STATES.name})'

CHUNK, LOOKAHEAD = 500, 1000
HERE = [1e-3, -0.5e-3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]


class Recorder:
    """trajectory.session.Outputs that keeps everything: rows by step (last one wins, as a
    servo reads a re-sent stream), and the session's state at every status publication."""

    def __init__(self):
        self.by_step, self.chunks, self.states, self.logs, self.warnings = {}, [], [], [], []
        self.goal_changes = []
        self.states_wanted = 0
        self.session = None

    def rows(self, first, positions, velocities, accelerations):
        self.chunks.append(first)
        for k, p in enumerate(positions):
            self.by_step[first + k] = p

    def status(self):
        self.states.append(self.session.status_values()['state'])

    def goal(self, goal):
        self.goal_changes.append((goal.uuid, goal.state.text, goal.reason))

    def log(self, text):
        self.logs.append(text)

    def warn(self, text):
        self.warnings.append(text)

    def want_state(self):
        self.states_wanted += 1


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
    assert session.home() == Answer(False, f'home: {NO_STATE}')
    values = session.status_values()
    assert values['state'] == 'idle' and values['rejected_goals'] == 2 and values['streamed_to_step'] == ''
    assert values['progress'] == '0' and values['feed_override'] == '1'
    assert values['last_rejection'] == f'home: {NO_STATE}'
    assert out.by_step == {} and out.states == ['idle', 'idle']
    assert out.warnings[0] == f'rejected joint goal: {NO_STATE}'
    # both goals are entered, aborted with the reason
    assert [(state, reason) for _, state, reason in out.goal_changes] == [
        ('aborted', f'joint goal: {NO_STATE}'), ('aborted', f'home: {NO_STATE}')]


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
        'feed_override', 'feed_override_setting', 'fault', 'rejected_goals', 'last_rejection', 'goal_id',
        'goal_status', 'reference_lost']


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


def test_hold_resume_and_stop_a_joint_move(micromill, out):
    """A joint move runs at the axis limits, where a feed ramp would take longer than the
    move: a hold cuts it with a time-optimal stop instead, for real, and resume goes on to
    the goal (the goal stays one goal: accepted, executing, succeeded)."""
    session = session_of(micromill, out, start_step=0)
    for command in (session.hold, session.resume, session.stop):
        assert command() == Answer(False, 'not applicable while idle')
    session.accept_joint_goal(['x_c'], [[-40e-3]], [0.0], stamp=(7, 5))      # full feed: 0.35 s from step 1000
    goal = session.goal
    session.tick(2000)
    answer = session.hold()
    assert answer.success and answer.message.startswith('stopping from step 2500, at rest at step ')
    assert session.state == State.HOLDING
    for step in range(2500, 40000, CHUNK):                            # the hold keeps the motion
        session.tick(step)
    assert session.state == State.HOLDING and session.status_values()['feed_override'] == '0.0000'
    _, rows = streamed(out)
    assert_within_limits(micromill, rows)
    still = rows[-1]
    assert -30e-3 < still[0] < HERE[0] - 1e-3 and (rows[-5000:] == still).all()   # stopped on the way
    assert session.home().message == 'home: busy (holding); one motion at a time'
    rest = len(move_to(micromill, [-40e-3] + HERE[1:], AxisState.at_rest(still)))
    first = session.stream.next_step                                  # the first row not yet streamed
    assert session.resume() == Answer(True, f'resuming from step {first}: {rest} steps to the end')
    assert session.state == State.RUNNING
    run_until_idle(session)
    _, rows = streamed(out)
    assert_within_limits(micromill, rows)
    assert abs(rows[-1][0] + 40e-3) < 1e-15                          # the goal, after all
    assert [c for c in out.goal_changes if c[0] == goal.uuid] == [
        (goal.uuid, 'accepted', ''), (goal.uuid, 'executing', ''), (goal.uuid, 'succeeded', '')]
    assert goal.stamp == (7, 5) and out.goal_changes[-2][1:] == ('aborted', 'home: busy (holding); one motion at a time')

    # stop: at rest short of the goal, the rest dropped, the goal canceled
    session.accept_joint_goal(['x_c'], [[40e-3]], [0.0])
    start = session.status_values()['motion_start_step']
    session.tick(start + 500)
    assert session.stop().success and session.state == State.HOLDING
    assert session.resume() == Answer(False, 'not applicable while holding (stopping)')   # a stop is not resumed
    assert session.goals.goals[-1].state.text == 'canceling'
    run_until_idle(session)
    _, rows = streamed(out)
    assert_within_limits(micromill, rows)
    assert -40e-3 < rows[-1][0] < 0.0 and (rows[-1000:] == rows[-1]).all()
    stopped = session.goals.goals[-1].uuid
    assert out.goal_changes[-2:] == [(stopped, 'canceling', 'stopped'), (stopped, 'canceled', 'stopped')]
    assert out.states.count('holding') >= 3 and out.states[-1] == 'idle'


def test_a_hold_too_late_is_refused_and_the_goal_succeeds(micromill, out):
    session = session_of(micromill, out, start_step=0)
    session.accept_joint_goal(['x_c'], [[3e-3]], [0.0])              # 863 steps from step 1000
    session.tick(1200)                                                # acts from 1700: braking already
    answer = session.hold()
    assert not answer.success and answer.message.startswith('too late: the joint goal (1 points) is braking')
    session.tick(1500)                                                # acts from 2000: after the end
    assert session.stop() == Answer(False, 'too late: the joint goal (1 points) ends at step 1862 at rest, '
                                           'before a stop could act (from step 2000)')
    assert session.state == State.RUNNING
    run_until_idle(session)
    assert out.goal_changes[-1][1] == 'succeeded'


def test_waypoints_held_and_resumed_still_stop_at_each_waypoint(micromill, out):
    session = session_of(micromill, out, start_step=0)
    session.accept_joint_goal(['x_c', 'y_c'], [[-20e-3, 0.0], [-20e-3, 10e-3]], [0.0, 0.0])
    session.tick(500)
    assert session.hold().success                                     # at the first step of the motion
    session.tick(5000)
    _, rows = streamed(out)
    assert (rows[1000:] == HERE).all()                                # held before it began
    assert session.resume().success
    run_until_idle(session)
    _, rows = streamed(out)
    at_first = np.flatnonzero(np.abs(rows - ([-20e-3, 0.0] + HERE[2:])).max(axis=1) < 1e-12)
    assert at_first.size and abs(rows[-1][1] - 10e-3) < 1e-15

    # held in the first move: resume heads for the first waypoint, then the second
    session.accept_joint_goal(['x_c', 'y_c'], [[20e-3, 10e-3], [20e-3, -10e-3]], [0.0, 0.0])
    start = session.status_values()['motion_start_step']
    session.tick(start - 300)
    assert session.hold().success
    session.tick(start + 5000)
    _, rows = streamed(out)
    still = rows[-1]
    assert -20e-3 < still[0] < 20e-3
    assert session.resume().success
    run_until_idle(session)
    _, rows = streamed(out)
    assert_within_limits(micromill, rows)
    after = rows[start + 5000:]
    assert np.flatnonzero(np.abs(after[:, :2] - [20e-3, 10e-3]).max(axis=1) < 1e-12).size
    np.testing.assert_allclose(rows[-1][:2], [20e-3, -10e-3], rtol=0, atol=1e-15)


def test_timed_waypoint_held_still_arrives_no_earlier_than_asked(micromill, out):
    session = session_of(micromill, out, start_step=0)
    session.accept_joint_goal(['x_c'], [[2e-3]], [1.0])              # 1 mm in no less than 1 s
    start = session.status_values()['motion_start_step']
    session.tick(start + 1000)                                        # hold at 0.15 s of planned time
    assert session.hold().success
    session.tick(start + 5000)
    assert session.resume().success
    resumed = session.stream.motion
    cut = start + 1500
    assert (len(resumed.reference) - 1) * micromill.control_period >= 1.0 - (cut - start) * 1e-4 - 1e-9


def test_cancel_acts_on_the_active_goal_by_id(micromill, out):
    from trajectory.session import CancelCode
    session = session_of(micromill, out, start_step=0)
    assert session.cancel() == (CancelCode.NONE, [])                 # nothing to cancel
    session.accept_joint_goal(['x_c'], [[-40e-3]], [0.0], stamp=(1, 0))
    goal = session.goal
    assert session.cancel(b'x' * 16) == (CancelCode.UNKNOWN_GOAL_ID, [])
    assert session.cancel(None, before=(0, 5)) == (CancelCode.NONE, [])   # accepted after that stamp
    session.tick(1500)
    assert session.cancel(goal.id) == (CancelCode.NONE, [goal])
    assert goal.state.text == 'canceling' and goal.reason == 'canceled'
    run_until_idle(session)
    assert goal.state.text == 'canceled' and session.goal is None
    assert session.cancel(goal.id) == (CancelCode.GOAL_TERMINATED, [])
    # while planning: the plan is dropped
    session.planning('path of 24 points', stamp=(2, 0))
    planned = session.goal
    assert session.cancel() == (CancelCode.NONE, [planned])
    assert planned.state.text == 'canceled' and session.state == State.IDLE and not session.awaiting_plan


def test_goal_ids_are_deterministic_and_the_book_keeps_the_recent_goals(micromill):
    from trajectory.goals import GoalBook, GoalState
    changes = []
    runs = []
    for _ in range(2):
        book = GoalBook(changes.append, keep=3)
        active = book.new('path', 'path of 6 points', (5, 10))
        book.set(active, GoalState.ACCEPTED)
        for i in range(5):
            book.refuse('joint goal', 'joint goal (1 points)', (6, i), 'joint goal: busy (planning)')
        runs.append([g.uuid for g in book.goals])
        assert book.goals[0] is active and len(book.goals) == 3       # the active goal is kept
        assert book.goals[-1].state == GoalState.ABORTED and book.goals[-1].reason == 'joint goal: busy (planning)'
    assert runs[0] == runs[1] and len(set(runs[0])) == 3
    assert active.values()['stamp'] == '5.000000010' and active.values()['status'] == 'accepted'


def test_home_moves_to_the_machine_home(micromill, out):
    session = session_of(micromill, out, start_step=0)
    expected = len(move_to(micromill, micromill.home, AxisState.at_rest(HERE)))
    answer = session.home()
    assert answer.success and answer.message == f'homing in {expected} steps (goal {session.goal.uuid})'
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
    assert [c[1:] for c in out.goal_changes] == [
        ('accepted', ''), ('aborted', 'joint goal: busy (planning); one motion at a time'),
        ('aborted', 'path: planning failed: the path is out of reach inside the strokes')]

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
    assert out.goal_changes[-1][1:] == ('aborted', 'machine faulted: missing command for x_c') and session.goal is None
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


def test_a_lock_step_fault_reported_before_a_step_already_seen_is_stale_and_ignored(micromill, out):
    """A lock-step hw_sim holds its step while faulted: a fault of step 2500 arriving when the
    machine has run to step 3000 was reset since (a report held up by a link that was down,
    test_two_hosts); the goal goes on. One of the current step faults the session."""
    session = session_of(micromill, out, start_step=0)
    session.accept_joint_goal(['x_c'], [[-40e-3]], [0.0])
    session.tick(3000)
    session.machine_status(True, 'missing command for x_c', '2500', holds_step=True)
    assert session.state != State.FAULT and session.goal is not None
    assert out.logs[-1] == ('ignored a fault reported at step 2500, before step 3000 the machine has run since '
                            '(reset): missing command for x_c')
    session.machine_status(True, 'missing command for x_c', '3000', holds_step=True)
    assert session.state == State.FAULT and out.goal_changes[-1][1] == 'aborted'


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


def test_a_path_is_held_on_the_path_and_its_approach_by_a_stop(micromill, out):
    """On the path part a hold is the feed ramp (it stays on the path); during the approach
    (a point-to-point move) the approach is cut, and resume approaches the path again."""
    a, b = [-40e-3] + HERE[1:], [-40e-3, 1e-3] + HERE[2:]
    path = move_to(micromill, b, AxisState.at_rest(a), scale=0.05)            # "the path": slow
    approach = len(move_to(micromill, a, AxisState.at_rest(HERE)))
    session = session_of(micromill, out, start_step=0)
    session.planning('path of 24 points')
    session.path_planned(path)
    start = session.status_values()['motion_start_step']
    session.tick(start + 500)                                         # in the approach: cut
    answer = session.hold()
    assert answer.success and 'time-optimal stop of the move' in answer.message
    session.tick(start + 5000)
    still = streamed(out)[1][-1]
    assert -40e-3 + 1e-3 < still[0] < HERE[0] - 1e-3
    assert session.resume().success
    restart = session.status_values()['motion_start_step']
    session.tick(restart + len(move_to(micromill, a, AxisState.at_rest(still))) + 1000)   # on the path
    answer = session.hold()
    assert answer.success and answer.message.startswith('feed 0 from step ')
    session.tick(session.step + 40000)
    assert session.state == State.HOLDING and session.status_values()['feed_override'] == '0.0000'
    assert session.resume().success
    run_until_idle(session)
    _, rows = streamed(out)
    assert_within_limits(micromill, rows)
    np.testing.assert_allclose(rows[-1], b, rtol=0, atol=1e-15)
    assert out.goal_changes[-1][1] == 'succeeded' and approach > 3000


def clock(session, now: float, step: int) -> None:
    """A /clock `step` at wall time `now`, as the node takes it: the stall check, then the tick."""
    session.watch(now)
    session.tick(step)


def test_a_stall_of_the_node_aborts_its_goal_and_nothing_of_it_goes_on(micromill, out):
    """README "Faults": the node's process did not run for more than its stall limit (by
    default contract.STALL_LIMIT, half the liveliness lease: clients may have taken it for
    lost): the goal is aborted and its motion stopped, once a machine state sent after the
    stall gives the sim time."""
    session = session_of(micromill, out, start_step=0)
    clock(session, 10.0, 0)
    assert session.accept_joint_goal(['x_c'], [[-40e-3]], [0.0])
    clock(session, 10.05, 2000)
    assert session.state == State.RUNNING
    assert session.stall_limit == contract.STALL_LIMIT
    clock(session, 10.05 + 0.9 * contract.STALL_LIMIT, 2000)     # below the limit: no stall
    assert session.state == State.RUNNING and out.states_wanted == 0
    stood = 1.2 * contract.STALL_LIMIT
    clock(session, 10.05 + 0.9 * contract.STALL_LIMIT + stood, 2000)
    assert out.states_wanted == 1 and out.goal_changes[-1][1] == 'executing'    # the sim time asked for
    session.machine_state(HERE, 2010)
    assert out.goal_changes[-1][1] == 'aborted'
    assert out.goal_changes[-1][2] == f'trajectory stalled: its process did not run for {stood:.1f} s (stopped or starved)'
    run_until_idle(session)
    _, rows = streamed(out)
    assert abs(rows[-1][0] - (HERE[0] - 40e-3)) > 10e-3     # stopped far short of the goal
    assert (rows[-50:] == rows[-1]).all()         # and at rest
    session.watch(now=20.0)                       # idle: a gap is no stall of a goal
    assert session.state == State.IDLE and out.states_wanted == 1


@pytest.mark.parametrize('seen_by', ['timer', 'clock'])
def test_a_stall_waits_for_a_fresh_machine_state_and_holds_the_last_row_the_servos_had(micromill, out, seen_by):
    """A stall seen from a timer (the newest step known is from before it) or from a /clock
    step of the stall's gap (the reader's queue still holds them): nothing is streamed until
    a machine state sent after the stall; the sim went on meanwhile and the servos ran out of
    rows, so the stream holds the last row they had. No stop planned from the past steps,
    which would take them back along the motion; no rows from them, which would move the
    servos on from where they stand."""
    session = session_of(micromill, out, start_step=0)
    clock(session, 10.0, 0)
    assert session.accept_joint_goal(['x_c'], [[-40e-3]], [20.0])     # 20 s long
    for step in range(CHUNK, 20 * CHUNK + 1, CHUNK):
        session.tick(step)
    last = max(out.by_step)
    had = out.by_step[last]
    if seen_by == 'timer':
        session.watch(now=10.0 + 2 * contract.STALL_LIMIT)
    else:
        clock(session, 10.0 + 2 * contract.STALL_LIMIT, 21 * CHUNK)  # a step of the gap, queued
    assert session.state == State.RUNNING and out.goal_changes[-1][1] == 'executing' and out.states_wanted == 1
    for step in range(21 * CHUNK, 24 * CHUNK + 1, CHUNK):           # more steps of the gap
        clock(session, 10.01 + 2 * contract.STALL_LIMIT, step)
    assert max(out.by_step) == last and out.goal_changes[-1][1] == 'executing'   # nothing streamed, nothing cut
    session.machine_state(HERE, last + 5 * CHUNK)                   # the sim ran past the rows
    assert out.goal_changes[-1][1] == 'aborted' and out.goal_changes[-1][2].startswith('trajectory stalled')
    session.reference_broken('servo_coarse', str(last + 1), 30.0)   # their break at the rows' end: mended by the hold
    assert out.states_wanted == 1 and not session.rejoining
    session.tick(last + 5 * CHUNK)
    assert session.state == State.IDLE
    assert all(out.by_step[k] == had for k in range(last, max(out.by_step) + 1))   # held there
    assert abs(had[0] - HERE[0]) > 1e-3                        # a row under way, not the start


def test_a_stall_waiting_for_the_sim_time_aborts_no_later_goal(micromill, out):
    """The goal under way at a stall ends otherwise before the machine state comes (hw_sim
    faults), the machine is reset and a new goal accepted: that goal is streamed, and the
    state, when it comes, does not abort it for the old stall."""
    session = session_of(micromill, out, start_step=0)
    clock(session, 10.0, 0)
    assert session.accept_joint_goal(['x_c'], [[-40e-3]], [20.0])
    session.tick(CHUNK)
    session.watch(now=10.0 + 2 * contract.STALL_LIMIT)            # the stall
    session.machine_status(True, 'missing command for x_c', str(CHUNK + 1))
    assert session.state == State.FAULT and out.goal_changes[-1][1:] == ('aborted', 'machine faulted: missing '
                                                                          'command for x_c')
    session.machine_status(False)                                # reset
    assert session.state == State.IDLE
    assert session.accept_joint_goal(['x_c'], [[-41e-3]], [0.0])
    streamed_to = max(out.by_step)
    clock(session, 10.05 + 2 * contract.STALL_LIMIT, CHUNK + 2)
    session.tick(3 * CHUNK)
    assert max(out.by_step) > streamed_to                        # streamed: the stall waits for no state now
    session.machine_state(HERE, 3 * CHUNK)
    assert session.state == State.RUNNING and out.goal_changes[-1][1] in ('accepted', 'executing')


def test_the_stall_limit_is_the_sessions_own(micromill, out):
    """The trajectory node's `stall_limit` parameter: a gap of 4 s aborts nothing under a
    5 s limit; after a change to 2 s (live), a gap of 2.5 s aborts the goal."""
    session = Session(micromill, out, CHUNK, LOOKAHEAD, stall_limit=5.0)
    out.session = session
    session.start_streaming(HERE, 0)
    clock(session, 10.0, 0)
    assert session.accept_joint_goal(['x_c'], [[-40e-3]], [0.0])
    clock(session, 14.0, 2000)
    assert session.state == State.RUNNING and out.goal_changes[-1][1] == 'executing' and out.states_wanted == 0
    session.stall_limit = 2.0
    clock(session, 16.5, 2000)
    session.machine_state(HERE, 2000)
    assert out.goal_changes[-1][1:] == ('aborted', 'trajectory stalled: its process did not run for 2.5 s '
                                        '(stopped or starved)')


CHECK = 0.05      # s, the trajectory node's timer that confirms a loss (check_planning)


def checked(report, start: float, end: float) -> None:
    """`report(now)` at the node's cadence from `start` up to `end` (both included)."""
    for k in range(round((end - start) / CHECK) + 1):
        report(start + k * CHECK)


def test_hw_sim_lost_is_a_fault_once_confirmed_and_clears_when_it_is_back_and_healthy(micromill, out):
    session = session_of(micromill, out, start_step=0)
    assert session.accept_joint_goal(['x_c'], [[-40e-3]], [0.0])
    session.tick(2000)
    lost = functools.partial(session.machine_alive, False)
    checked(lost, 5.0, 5.2)                       # the lease ran out ...
    session.machine_heard(now=5.22)               # ... but hw_sim's status came after: a false loss
    checked(lost, 5.25, 5.25 + contract.LOSS_CONFIRM - CHECK)
    assert session.state == State.RUNNING
    lost(now=5.25 + contract.LOSS_CONFIRM)        # lost, and silent for LOSS_CONFIRM: confirmed
    reason = f'hw_sim lost: no sign of life within its {contract.LIVELINESS_LEASE:g} s liveliness lease (killed, stopped or hung)'
    assert session.state == State.FAULT and session.fault == reason
    assert out.goal_changes[-1][1:] == ('aborted', f'machine faulted: {reason}')
    session.machine_status(False)                 # a healthy status while still lost: stays faulted
    assert session.state == State.FAULT
    session.machine_alive(True, now=10.0)
    session.machine_status(True, 'hw_sim stalled: its process did not run for 3.0 s', '2100')
    assert session.fault == 'hw_sim stalled: its process did not run for 3.0 s'   # its own fault step now
    session.machine_status(False)                 # reset
    assert session.state == State.IDLE and session.fault == ''


def test_a_loss_is_not_confirmed_across_a_stall_of_the_watching_node(micromill, out):
    """A CI run of a single-process graph: hw_sim's lease ran out, then the process did not
    run for ~2 s (neither this node's checks nor hw_sim's 1 Hz status); the first check after
    the stall came before hw_sim's status and confirmed a false loss. A check later than
    contract.LOSS_CHECK_GAP after the one before starts the confirmation over."""
    session = session_of(micromill, out, start_step=0)
    assert session.accept_joint_goal(['x_c'], [[-40e-3]], [0.0])
    session.tick(2000)
    lost = functools.partial(session.machine_alive, False)
    checked(lost, 5.0, 5.2)
    stall = contract.LOSS_CONFIRM + 0.5
    assert stall > contract.LOSS_CHECK_GAP
    lost(now=5.2 + stall)                         # 2.2 s after the report, the first check after the stall
    assert session.state == State.RUNNING
    session.machine_heard(now=5.2 + stall + 0.3)  # hw_sim's status, queued behind it
    checked(lost, 5.2 + stall + 0.35, 5.2 + stall + 0.35 + contract.LOSS_CONFIRM - CHECK)
    assert session.state == State.RUNNING         # heard: no loss
    session.machine_alive(True)                   # and its lease asserted again
    # a real loss, the node checking on time after a stall: confirmed LOSS_CONFIRM after the stall
    session.tick(2100)
    lost(now=20.0)
    checked(lost, 21.0, 21.0 + contract.LOSS_CONFIRM - CHECK)
    assert session.state == State.RUNNING
    lost(now=21.0 + contract.LOSS_CONFIRM)
    assert session.state == State.FAULT and session.fault.startswith('hw_sim lost')


def test_the_compensation_node_lost_aborts_the_goal_and_refuses_goals_until_it_is_back(micromill, out):
    """README "Faults": with compensation in the chain, its loss (confirmed as hw_sim's) means
    the reference no longer reaches the servos: the goal is aborted naming it, nothing of the
    motion goes on, nothing more is streamed, and goals are refused until it is back and the
    stream is taken up again from a machine state (where the servos held)."""
    session = session_of(micromill, out, start_step=0)
    assert session.accept_joint_goal(['x_c'], [[-40e-3]], [0.0])
    session.tick(2000)
    lost = functools.partial(session.chain_alive, 'compensation', False)
    checked(lost, 3.0, 3.15)
    session.chain_heard(now=3.17)                 # its status came after the report: a false loss
    checked(lost, 3.25, 3.25 + contract.LOSS_CONFIRM - CHECK)
    assert session.state == State.RUNNING and session.status_values()['reference_lost'] == ''
    lost(now=3.25 + contract.LOSS_CONFIRM)        # silent for LOSS_CONFIRM since 3.25: confirmed
    reason = (f'compensation lost: no sign of life within its {contract.LIVELINESS_LEASE:g} s liveliness lease '
              '(killed, stopped or hung); '
              'the reference does not reach the servos')
    assert out.goal_changes[-1][1:] == ('aborted', reason)
    assert session.status_values()['reference_lost'] == reason
    streamed_to = max(out.by_step)
    run_until_idle(session)
    # its stop is not streamed: what the compensation node would forward on its return (rows
    # at rest where the stop ends) is not where the servos stand
    assert max(out.by_step) == streamed_to
    assert not session.accept_joint_goal(['x_c'], [[0.0]], [0.0])
    assert session.rejections.last == f'joint goal: {reason}'
    streamed_to = max(out.by_step)
    session.tick(session.step + 10 * LOOKAHEAD)
    assert max(out.by_step) == streamed_to                       # nothing streamed while it is lost
    session.chain_alive('compensation', True)
    assert out.states_wanted == 1
    waiting = 'compensation back: waiting for the machine state to hold where the servos stand'
    assert session.status_values()['reference_lost'] == waiting
    assert not session.accept_joint_goal(['x_c'], [[0.0]], [0.0])
    assert session.rejections.last == f'joint goal: {waiting}'
    session.chain_alive('compensation', True)                    # liveliness again: one state asked for
    assert out.states_wanted == 1 and max(out.by_step) == streamed_to
    # the servos held a row of the motion before its stop: the stream goes on from there
    stood, at = list(HERE), session.step - 3
    stood[0] = HERE[0] - 7e-3
    session.machine_state(stood, at)
    assert session.status_values()['reference_lost'] == '' and session.state == State.IDLE
    assert out.logs[-1] == (f'compensation back: holding where the servos stand (the measured position, from step '
                            f'{at}); goals accepted again')
    assert min(out.by_step) <= at and max(out.by_step) >= session.step + LOOKAHEAD
    assert all(out.by_step[k] == tuple(stood) for k in range(at, max(out.by_step) + 1))
    assert session.accept_joint_goal(['x_c'], [[stood[0] + 1e-3]], [0.0])


def test_back_after_the_servos_broke_the_stream_holds_the_row_they_hold(micromill, out):
    """The servos ran out of rows while compensation was lost and report the break (their
    /diagnostics `reference_broken_step` E): the stream is taken up again from the row this
    node handed out for step E - 1, which they hold, not from the measured position (which has
    compensation's correction and the dual-stage offsets in it: they would be added again).
    Breaks reported at another step by another node, or from before the stream's last start,
    leave the measured position."""
    session = session_of(micromill, out, start_step=0)
    assert session.accept_joint_goal(['x_c'], [[-40e-3]], [0.0])
    for step in range(CHUNK, 6 * CHUNK + 1, CHUNK):
        session.tick(step)
    lost = functools.partial(session.chain_alive, 'compensation', False)
    checked(lost, 3.0, 3.0 + contract.LOSS_CONFIRM)
    assert out.goal_changes[-1][1] == 'aborted'
    broke = 4 * CHUNK + 7
    had = out.by_step[broke - 1]
    assert abs(had[0] - HERE[0]) > 1e-6                            # a row under way
    for who in ('servo_coarse', 'servo_fine', 'dual_stage'):
        session.reference_broken(who, str(broke), 0.0)
    session.reference_broken('servo_fine', 'x', 0.0)                     # no step: ignored
    session.chain_alive('compensation', True)
    measured = list(had)
    measured[3] += 5e-6                                             # x_f: the correction in it once more
    session.machine_state(measured, 6 * CHUNK + 3)
    assert out.logs[-1] == (f'compensation back: holding where the servos stand (the row of step {broke - 1}, '
                            f'before their reference broke, from step {6 * CHUNK + 3}); goals accepted again')
    assert all(out.by_step[k] == tuple(had) for k in range(6 * CHUNK + 3, 6 * CHUNK + 3 + LOOKAHEAD))
    # lost again; back with breaks at two steps (one node got a chunk the others did not)
    checked(lost, 5.0, 5.0 + contract.LOSS_CONFIRM)
    session.reference_broken('servo_coarse', str(7 * CHUNK), 0.0)
    session.reference_broken('servo_fine', str(7 * CHUNK + 1), 0.0)
    session.chain_alive('compensation', True)
    session.machine_state(measured, 8 * CHUNK)
    assert out.logs[-1].startswith('compensation back: holding where the servos stand (the measured position')
    assert out.by_step[8 * CHUNK] == tuple(measured)
    # lost again; the breaks known are from before the last start: the measured position
    checked(lost, 7.0, 7.0 + contract.LOSS_CONFIRM)
    session.chain_alive('compensation', True)
    session.machine_state(HERE, 9 * CHUNK)
    assert out.logs[-1].startswith('compensation back: holding where the servos stand (the measured position')


def test_a_break_without_a_lost_link_aborts_the_goal_and_takes_the_stream_up_where_the_machine_stands(
        micromill, out):
    """The stream fell behind (no link lost): a servo ran out while moving and holds, refusing
    the rest of the motion. Reported during the goal, the goal goes on until no lost link has
    explained it within a liveliness lease and its confirmation; then it is aborted naming the
    servo, and the stream, after nothing more for the state read, holds the measured position
    (other nodes may not have broken). Reported when idle, the same at once. The same report
    again, or one from before the stream's last start, changes nothing."""
    session = session_of(micromill, out, start_step=0)
    assert session.accept_joint_goal(['x_c'], [[-40e-3]], [0.0])
    for step in range(CHUNK, 4 * CHUNK, CHUNK):
        session.tick(step)
    broke = 3 * CHUNK + 11
    session.reference_broken('servo_coarse', str(broke), 10.0)
    due = 10.0 + contract.LIVELINESS_LEASE + contract.LOSS_CONFIRM
    session.check_breaks(due - 0.05)
    assert session.state == State.RUNNING and out.goal_changes[-1][1] == 'executing' and out.states_wanted == 0
    session.check_breaks(due)
    waiting = (f'servo_coarse: its reference broke at step {broke} while moving; waiting for the machine state to '
               'take it up again where the machine stands')
    assert out.goal_changes[-1][1:] == ('aborted', f'servo_coarse: its reference broke at step {broke} while moving '
                                        '(the rows came too late); it holds there')
    assert session.state == State.IDLE and out.states_wanted == 1 and out.warnings[-1] == waiting
    assert session.status_values()['reference_lost'] == waiting
    assert not session.accept_joint_goal(['x_c'], [[0.0]], [0.0]) and session.rejections.last == f'joint goal: {waiting}'
    streamed_to = max(out.by_step)
    session.tick(4 * CHUNK)
    assert max(out.by_step) == streamed_to                       # nothing streamed until the state
    stood = list(out.by_step[broke - 1])
    session.machine_state(stood, 4 * CHUNK + 2)
    assert out.logs[-1] == ('reference taken up again: holding where the servos stand (the measured position, from '
                            f'step {4 * CHUNK + 2}); goals accepted again')
    assert all(out.by_step[k] == tuple(stood) for k in range(4 * CHUNK + 2, 4 * CHUNK + 2 + LOOKAHEAD))
    assert session.status_values()['reference_lost'] == ''
    session.reference_broken('servo_coarse', str(broke), 20.0)     # its next report, idle: mended already
    session.reference_broken('servo_fine', '5', 20.0)
    assert out.states_wanted == 1
    session.reference_broken('servo_fine', str(5 * CHUNK), 21.0)   # a new break, idle: at once
    assert out.states_wanted == 2 and session.rejoining


def test_a_goal_whose_servo_broke_does_not_succeed_when_its_motion_plays_out_first(micromill, out):
    """A break reported during a short goal that plays out before the break is due
    (check_breaks): the servo stopped short of the end, so the goal is aborted naming it, not
    succeeded, and the stream taken up again where the machine stands."""
    session = session_of(micromill, out, start_step=0)
    assert session.accept_joint_goal(['x_c'], [[HERE[0] + 1e-3]], [0.0])
    session.tick(CHUNK)
    session.reference_broken('servo_coarse', str(CHUNK + 1), 10.0)
    run_until_idle(session)
    assert out.goal_changes[-1][1:] == ('aborted', f'servo_coarse: its reference broke at step {CHUNK + 1} while '
                                        'moving (the rows came too late); it holds there')
    assert session.rejoining and out.states_wanted == 1
    session.check_breaks(100.0)                                    # nothing due any more
    assert out.states_wanted == 1


def test_a_hold_stop_or_feed_change_waits_for_a_stalls_machine_state(micromill, out):
    """Between a stall and the machine state its abort waits for, a hold, resume or stop is
    refused with the reason and a feed override changes only the setting: each would plan
    from a step of before the stall (the newest known), re-sending rows behind the servos."""
    session = session_of(micromill, out, start_step=0)
    clock(session, 10.0, 0)
    assert session.accept_joint_goal(['x_c'], [[-40e-3]], [20.0])
    clock(session, 10.05, CHUNK)
    session.watch(now=10.05 + 2 * contract.STALL_LIMIT)
    streamed_to = max(out.by_step)
    refused = ('trajectory stalled: its process did not run for 6.0 s (stopped or starved): its goal is aborted '
               'once a machine state shows how far the servos got')
    assert session.hold() == Answer(False, refused)
    assert session.stop() == Answer(False, refused)
    assert session.resume() == Answer(False, refused)
    assert session.set_feed_override(0.5) and session.override_setting == 0.5
    assert max(out.by_step) == streamed_to and session.state == State.RUNNING
    session.machine_state(HERE, 2 * CHUNK)
    assert out.goal_changes[-1][1] == 'aborted'


def test_a_lost_chain_lost_again_before_its_state_came_waits_for_the_next_return(micromill, out):
    """The state asked for at a return that is lost again before it came does not take the
    stream up again; the next return asks again."""
    session = session_of(micromill, out, start_step=0)
    lost = functools.partial(session.chain_alive, 'compensation', False)
    for start in (1.0, 3.0):
        checked(lost, start, start + contract.LOSS_CONFIRM)
        assert session.status_values()['reference_lost'].startswith('compensation lost')
        session.chain_alive('compensation', True)
    assert out.states_wanted == 2
    checked(lost, 5.0, 5.0 + contract.LOSS_CONFIRM)
    session.machine_state(HERE, session.step)                    # the state of the return before
    assert session.status_values()['reference_lost'].startswith('compensation lost')
    assert not session.accept_joint_goal(['x_c'], [[0.0]], [0.0])
    session.chain_alive('compensation', True)
    assert out.states_wanted == 3
    session.machine_state(HERE, session.step)
    assert session.accept_joint_goal(['x_c'], [[0.0]], [0.0])
