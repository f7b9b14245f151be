"""hw_sim's stepping without ROS (hw_sim.session, hw_sim.lockstep): which events advance,
re-send, hold, refuse or fault, on fake wall time passed in (no sleeps, no DDS). The graph
tests (test_hw_sim_faults.py, test_recorder_graph.py) check the same over real DDS."""
import math

import pytest

from hw_sim.lockstep import LockStep, RecorderGate
from hw_sim.session import LockStepSession, PacedSession
from hw_sim.simulator import MachineSimulator
from machine_ctrl.contract import StepClock

AXES = ('x_c', 'y_c', 'z_c', 'x_f', 'y_f', 'z_f', 'a_f', 'b_f', 'c_f')
COARSE, FINE = AXES[:3], AXES[3:]
PERIOD_NS = 100_000                          # micromill: 10 kHz


def stamp(step):
    """(sec, nanosec) of a micromill step, written out here rather than taken from StepClock."""
    return divmod(step * PERIOD_NS, 1_000_000_000)


class FakeIO:
    """Records what the session asks of its node; answers the graph questions from fields."""

    def __init__(self):
        self.events = []
        self.subscribers, self.recorder = 0, True
        self.sim, self.sent = None, {}           # step -> the measurement last sent with it

    def publish_state(self, step):
        self.events.append(('state', step))
        self.sent[step] = self.sim.measurement

    def report_fault(self, reason):
        self.events.append(('fault', reason))

    def refuse_command(self, reason):
        self.events.append(('refused', reason))

    def refuse_progress(self, reason):
        self.events.append(('refused progress', reason))

    def log_info(self, text):
        self.events.append(('info', text))

    def state_subscribers(self):
        return self.subscribers

    def recorder_connected(self):
        return self.recorder

    def states(self):
        return [e[1] for e in self.events if e[0] == 'state']

    def take(self):
        events, self.events = self.events, []
        return events


@pytest.fixture
def make(micromill):
    def make(kind=LockStepSession, **params):
        io = FakeIO()
        session = kind(MachineSimulator(micromill), StepClock(1e-4), io, **params)
        io.sim = session.sim
        session.start(now=0.0)
        return session, io
    return make


def command(session, step, axes=AXES, values=None, now=0.0):
    values = [0.0] * len(axes) if values is None else values
    session.on_command(*stamp(step), list(axes), values, now)


# -- lock-step ---------------------------------------------------------------------------

def test_advances_once_every_axis_has_answered_the_step(make):
    s, io = make()
    assert io.take() == [('state', 0)]
    command(s, 0, COARSE)                         # the coarse servos answer first
    assert io.take() == [] and s.step == 0
    command(s, 0, FINE)                           # the run begins: step 0 once more, then 1
    assert io.take() == [('state', 0), ('state', 1)] and s.step == 1
    command(s, 1, FINE)                           # either order
    command(s, 1, COARSE)
    assert io.take() == [('state', 2)]


def test_the_run_is_the_bare_simulator_whatever_the_timing_of_the_messages(make, micromill):
    """Lock-step determinism: stale, repeated, refused and early messages and re-sends change
    nothing; the states are those of a simulator stepped with each step's commands."""
    s, io = make()
    reference = MachineSimulator(micromill)
    expected = [reference.measurement]
    for k in range(30):
        coarse = [1e-3 * math.sin(0.3 * k + i) for i in range(3)]
        fine = [1e-4 * math.cos(0.2 * k + i) for i in range(6)]
        command(s, k, COARSE, [9.0, 9.0, 9.0], now=k)
        command(s, k, COARSE, coarse, now=k)                   # a later message for the step overrides
        if k > 0:
            command(s, k - 1, AXES, [5.0] * 9, now=k)          # stale: dropped
        command(s, k + 3, AXES, [5.0] * 9, now=k)              # future: refused
        s.on_timer(now=k + 0.5)                                # re-send of the state waited on
        command(s, k, FINE, fine, now=k)
        expected.append(reference.step(coarse + fine))
    assert s.step == 30 and s.sim.fault is None
    assert [io.sent[k] for k in range(31)] == expected
    states = io.states()
    assert sorted(set(states)) == list(range(31)) and states == sorted(states)
    assert s.lockstep.stats.stale == 29 and s.lockstep.stats.refused == 30


def test_the_last_message_for_a_step_wins_until_the_step_is_taken(make, micromill):
    s, _ = make()
    command(s, 0, COARSE, [9.0, 9.0, 9.0])
    command(s, 0, COARSE, [1e-3, 2e-3, 3e-3])
    command(s, 0, FINE, [0.0] * 6)
    reference = MachineSimulator(micromill)
    assert s.sim.measurement == reference.step([1e-3, 2e-3, 3e-3] + [0.0] * 6)


@pytest.mark.parametrize('names, values, reason', [
    (['x_c', 'nope'], [0.0, 0.0], 'unknown axes nope'),
    (['x_c', 'x_c'], [0.0, 0.0], 'duplicate axis names'),
    (['x_c'], [0.0, 1.0], '1 names but 2 commands'),
])
def test_malformed_commands_are_refused_and_change_nothing(make, names, values, reason):
    s, io = make()
    io.take()
    s.on_command(*stamp(0), names, values, 0.0)
    command(s, 0, FINE)
    assert io.take() == [('refused', reason)] and s.step == 0 and s.lockstep.missing == list(COARSE)
    assert s.lockstep.stats.refused == 1 and s.lockstep.stats.last_refusal == reason


def test_commands_from_the_future_and_off_the_grid_are_refused(make):
    s, io = make()
    io.take()
    command(s, 5)
    s.on_command(0, 150_001, list(AXES), [0.0] * 9, 0.0)
    s.on_command(0, 1_500_000_000, list(AXES), [0.0] * 9, 0.0)
    assert io.take() == [('refused', 'command for step 5 while at step 0'),
                         ('refused', 'stamp 150001 ns is not on the 100000 ns control grid'),
                         ('refused', 'stamp nanosec 1500000000 is not in [0, 1e9)')]
    assert s.step == 0
    assert s.lockstep.stats.refused == 3          # stamps that are no step are counted too
    assert s.lockstep.stats.last_refusal == 'stamp nanosec 1500000000 is not in [0, 1e9)'


def test_a_non_finite_command_stops_the_machine_until_reset(make):
    s, io = make()
    for k in range(3):
        command(s, k)
    io.take()
    command(s, 3, AXES, [math.nan, 0.0, math.inf] + [0.0] * 6, now=1.0)
    reason = 'non-finite command for x_c, z_c'
    assert io.take() == [('fault', reason), ('state', 3)]
    assert s.sim.fault == reason
    assert s.status(1.0).message == f'FAULT: {reason}' and s.status(1.0).values['fault'] == reason
    command(s, 3, now=1.1)                         # the machine stays stopped
    s.on_timer(now=10.0)                           # no second fault, the state is re-sent
    assert io.take() == [('state', 3)] and s.step == 3
    assert s.reset(now=11.0) == f'reset at step 3 (cleared: {reason})'
    assert io.take() == [('state', 3)] and s.sim.fault is None
    command(s, 3, now=11.1)
    assert io.take() == [('state', 4)]
    assert s.reset(now=12.0) == 'reset at step 4'


def test_a_stroke_violation_is_reported_once(make):
    s, io = make()
    push = [0.0] * 9
    push[3] = 40.0                                 # x_f open loop
    for k in range(2000):
        if s.sim.fault is not None:
            break
        command(s, k, AXES, push)
    faults = [e for e in io.events if e[0] == 'fault']
    assert len(faults) == 1 and faults[0][1].startswith('stroke violation on x_f')
    assert io.events[-2:] == [faults[0], ('state', s.step)]


def test_a_missing_command_times_out_from_the_step_s_first_send_despite_re_sends(make):
    s, io = make(command_timeout=2.0, republish_period=0.2)
    command(s, 0, now=10.0)
    command(s, 1, COARSE, now=10.0)
    io.take()
    s.on_timer(now=10.1)                           # within the re-send period
    assert io.take() == []
    for t in (10.3, 10.6, 11.9):                   # re-sends do not restart the timeout
        s.on_timer(now=t)
        assert io.take() == [('state', 1)]
    s.on_timer(now=12.05)
    reason = 'missing command for x_f y_f z_f a_f b_f c_f (no answer to step 1 within 2 s)'
    assert io.take() == [('fault', reason), ('state', 1)]
    assert s.status(12.1).values['waiting_for'] == 'x_f y_f z_f a_f b_f c_f'


def test_no_timeout_at_step_0_while_the_graph_comes_up(make):
    s, io = make(command_timeout=2.0, republish_period=0.2)
    io.take()
    s.on_timer(now=100.0)
    assert io.take() == [('state', 0)] and s.sim.fault is None


def test_min_subscribers_holds_step_0_then_sends_it_again_and_starts(make):
    s, io = make(min_subscribers=2)
    io.subscribers = 1
    command(s, 0, now=0.05)
    s.on_timer(now=0.1)
    assert s.step == 0 and io.states() == [0]
    io.subscribers = 2                             # e.g. a recorder matched
    s.on_timer(now=0.15)
    assert io.states() == [0, 0, 1]
    io.subscribers = 0                             # asked only before the start
    command(s, 1, now=0.2)
    assert io.states()[-1] == 2


def test_the_graph_is_ready_once_it_has_completed_its_first_step(make):
    s, io = make(min_subscribers=1)
    command(s, 0, COARSE)
    assert not s.ready                             # the fine servos have not answered
    command(s, 0, FINE)
    assert not s.ready and s.step == 0             # every axis has, but held for a subscriber
    io.subscribers = 1
    s.on_timer(now=0.1)
    assert s.ready and s.step == 1 and s.status(0.1).values['ready'] is True
    s.fault('estop', now=0.2)
    s.reset(now=0.3)
    assert s.ready                                 # a fault does not make the graph less up


def test_paced_mode_is_ready_once_every_axis_has_been_commanded(make):
    s, _ = make(PacedSession)
    command(s, 0, COARSE)
    s.on_timer(now=0.001)
    assert not s.ready and s.step == 1             # stepping, but the fine axes have not spoken
    command(s, 0, FINE)                            # late (step 0 was taken), but they have
    assert s.ready


def test_timer_periods(make, micromill):
    assert make(command_timeout=2.0, republish_period=0.2)[0].timer_period == 0.2
    assert make(command_timeout=0.5, republish_period=0.2)[0].timer_period == 0.125
    assert make(PacedSession, real_time_factor=0.02)[0].timer_period == pytest.approx(1e-4 / 0.02)


def test_decimation_of_the_clock_and_the_ground_truth(make):
    s, _ = make(clock_decimation=10, truth_decimation=0)
    assert [k for k in range(25) if s.clock_due(k)] == [0, 10, 20]
    assert not any(s.truth_due(k) for k in range(25))
    s, _ = make(clock_decimation=1, truth_decimation=4)
    assert all(s.clock_due(k) for k in range(25))
    assert [k for k in range(13) if s.truth_due(k)] == [0, 4, 8, 12]


def test_diagnostics_keys(make):
    keys = ['step', 'mode', 'fault', 'waiting_for', 'stale_commands', 'refused_commands', 'last_refusal',
            'missed_deadlines', 'ready']
    gate_keys = ['recorder_window', 'recorder_step', 'holding_for_recorder', 'recorder_holds',
                 'recorder_hold_time', 'refused_progress', 'last_progress_refusal']
    s, _ = make()
    command(s, 0, COARSE)
    status = s.status(0.0)
    assert list(status.values) == keys and status.fault is None and status.message == 'running, step 0'
    assert status.values['mode'] == 'lockstep' and status.values['waiting_for'] == 'x_f y_f z_f a_f b_f c_f'
    assert list(make(recorder_window=5)[0].status(0.0).values) == keys + gate_keys
    paced_keys = ['overruns'] + [f'{name}_{what}' for name in ('step_latency', 'tick_lateness')
                                 for what in ('count', 'p50', 'p99', 'max')]
    paced = make(PacedSession)[0].status(0.0).values
    assert list(paced) == keys + paced_keys and paced['mode'] == 'paced' and paced['waiting_for'] == ''
    assert paced['step_latency_count'] == 0 and paced['step_latency_p99'] == '' and paced['overruns'] == 0


# -- the recorder window ------------------------------------------------------------------

def run_to(s, step, now=0.0):
    while s.step < step:
        before = s.step
        command(s, s.step, now=now)
        if s.step == before:
            return


def test_the_recorder_window_holds_without_a_fault_until_the_recorder_catches_up(make, micromill):
    s, io = make(recorder_window=3, command_timeout=2.0)
    run_to(s, 10)                                   # no recorder yet: nothing held
    assert s.step == 10
    s.on_progress(*stamp(2), now=1.0)              # recorder: written up to step 2
    assert ('info', 'recorder reports progress: holding at most 3 steps ahead') in io.take()
    command(s, 10, now=1.0)                        # 10 - 2 > 3: held, commands in hand
    assert s.step == 10
    s.on_timer(now=5.0)                            # longer than command_timeout: no fault
    assert s.sim.fault is None and s.step == 10
    values = s.status(5.5).values
    assert values['holding_for_recorder'] is True and values['recorder_holds'] == 1
    assert values['recorder_hold_time'] == '4.500' and values['recorder_step'] == 2
    s.on_progress(*stamp(8), now=6.0)              # may run to 8 + 3 + 1
    run_to(s, 20, now=6.0)
    assert s.step == 12
    assert s.status(6.0).values['recorder_hold_time'] == '5.000'
    s.on_timer(now=7.0)
    assert s.step == 12 and s.status(7.5).values['recorder_holds'] == 2
    reference = MachineSimulator(micromill)         # holding changed nothing
    for _ in range(12):
        reference.step([0.0] * 9)
    assert s.sim.measurement == reference.measurement


def test_a_recorder_that_leaves_releases_the_hold(make):
    s, io = make(recorder_window=3)
    run_to(s, 4)
    s.on_progress(*stamp(0), now=1.0)
    run_to(s, 10, now=1.0)
    assert s.step == 4
    io.recorder = False
    io.take()
    s.on_timer(now=2.0)
    assert io.take() == [('state', 4),             # re-sent: last sent 2 s ago
                         ('info', 'recorder left the graph: no longer holding for it'), ('state', 5)]
    values = s.status(3.0).values
    assert values['holding_for_recorder'] is False and values['recorder_step'] == ''
    assert values['recorder_hold_time'] == '1.000'
    run_to(s, 50, now=3.0)
    assert s.step == 50


@pytest.mark.parametrize('sec, nanosec, reason', [
    (0, 1, 'stamp 1 ns is not on the 100000 ns control grid'),
    (0, 500 * PERIOD_NS, 'progress for step 500, but the published steps are 0..7 (-1: none yet)'),
    (0, 1_500_000_000, 'stamp nanosec 1500000000 is not in [0, 1e9)'),
])
def test_bad_progress_is_refused_and_changes_nothing(make, sec, nanosec, reason):
    s, io = make(recorder_window=3)
    run_to(s, 7)
    io.take()
    s.on_progress(sec, nanosec, now=1.0)
    assert io.take() == [('refused progress', reason)]
    assert s.gate.recorded is None and s.gate.refused == 1 and s.gate.last_refusal == reason
    values = s.status(1.0).values
    assert values['refused_progress'] == 1 and values['last_progress_refusal'] == reason


def test_recorder_gate_counts_and_times_holds():
    gate = RecorderGate(window=2)
    assert not gate.holds(100)                     # no recorder has reported
    gate.recorded = 5
    assert not gate.holds(7) and gate.holds(8)
    gate.track(True, 1.0)
    gate.track(True, 2.0)                          # the same hold
    assert gate.hold_count == 1 and gate.held_for(2.5) == 1.5
    gate.track(False, 3.0)
    gate.track(True, 10.0)
    assert gate.hold_count == 2 and gate.held_for(10.25) == 2.25


def test_lockstep_takes_the_commands_in_axis_order():
    ls = LockStep(('a', 'b', 'c'))
    assert ls.offer(0, ['c', 'a'], [3.0, 1.0]) is None and not ls.complete() and ls.missing == ['b']
    assert ls.offer(0, ['b'], [2.0]) is None and ls.complete()
    assert ls.take() == [1.0, 2.0, 3.0] and ls.step == 1 and ls.missing == ['a', 'b', 'c']


def test_lockstep_checks_every_new_name_list_whatever_it_took_before():
    """Valid name lists are kept (checked once per list): a bad list is refused between good
    ones, a list and its reordering are each taken in their own order, ints taken as floats."""
    ls = LockStep(('a', 'b', 'c'))
    for _ in range(2):
        assert ls.offer(ls.step, ('a', 'b'), (1.0, 2.0)) is None
        assert ls.offer(ls.step, ['a', 'a'], [1.0, 2.0]) == 'duplicate axis names'
        assert ls.offer(ls.step, ('b', 'a'), (5.0, 4)) is None
        assert ls.offer(ls.step, ('b', 'z'), (5.0, 4.0)) == 'unknown axes z'
        assert ls.offer(ls.step, ('c',), (3.0,)) is None
        assert ls.offer(ls.step, ('a', 'b', 'c'), (1.0,)) == '3 names but 1 commands'
        taken = ls.take()
        assert taken == [4.0, 5.0, 3.0] and all(type(v) is float for v in taken)
    assert ls.stats.refused == 6 and ls.step == 2

# -- paced ---------------------------------------------------------------------------------

def test_paced_mode_steps_on_each_tick_and_holds_what_is_missing(make, micromill):
    s, io = make(PacedSession, real_time_factor=0.1)
    reference = MachineSimulator(micromill)
    first = [1e-3, -1e-3, 2e-3, 1e-4, 0.0, -1e-4, 1e-3, 0.0, 5e-4]
    command(s, 0, AXES, first)
    s.on_timer(now=0.001)
    reference.step(first)
    assert s.step == 1 and s.missed_deadlines == 0
    command(s, 0, COARSE, [9.0, 9.0, 9.0])         # for a step already taken: ignored
    command(s, 1, COARSE, [2e-3, 0.0, -2e-3])      # the fine axes miss this step
    s.on_timer(now=0.002)
    held = list(reference.applied[3:])
    reference.step([2e-3, 0.0, -2e-3] + held)
    assert s.step == 2 and s.missed_deadlines == 6
    s.on_timer(now=0.003)                          # nothing arrived: every axis holds
    reference.step(list(reference.applied))
    assert s.missed_deadlines == 15 and s.sim.fault is None
    assert s.sim.measurement == reference.measurement
    assert io.states() == [0, 1, 2, 3]


def test_paced_mode_faults_on_a_non_finite_command_too(make):
    s, io = make(PacedSession)
    io.take()
    command(s, 0, ['y_c'], [math.inf])
    assert io.take() == [('fault', 'non-finite command for y_c'), ('state', 0)]


def test_hw_sim_s_own_stall_faults_the_machine_from_step_1_on(make):
    """README "Faults": hw_sim's process not run (SIGSTOP, starved) for more than
    command_timeout: the machine stops rather than go on from a gap; never at step 0."""
    s, io = make(command_timeout=2.0)
    s.watch(now=50.0)                            # at step 0 the graph is still coming up
    assert s.sim.fault is None
    run_to(s, 3, now=50.0)
    s.watch(now=51.9)                            # within the timeout
    assert s.sim.fault is None
    io.take()
    s.watch(now=54.5)
    assert io.take() == [('fault', 'hw_sim stalled: its process did not run for 2.6 s (stopped or starved; '
                                   'limit command_timeout 2 s)'), ('state', 3)]
    command(s, 3, now=54.6)
    assert s.step == 3                            # faulted: nothing goes on without a reset


def test_a_short_stall_of_hw_sim_does_not_count_toward_the_servos_command_timeout(make):
    """run109: hw_sim stopped a little under command_timeout, its servos' answers waiting in its
    queue; the first timer call after it must not blame them. The time it did not run (beyond
    one timer period) moves the deadline; a servo that stays silent still faults, after
    command_timeout s of hw_sim running."""
    s, io = make(command_timeout=2.0, republish_period=0.2)     # timer period 0.2 s
    s.watch(now=50.0)
    run_to(s, 3, now=50.0)
    s.watch(now=50.15)
    s.watch(now=52.1)                              # stopped 1.95 s: not a stall of its own
    s.on_timer(now=52.1)                           # 2.1 s after step 3 went out
    assert s.sim.fault is None
    command(s, 3, now=52.11)                       # the answers it had not taken yet
    assert s.step == 4 and s.sim.fault is None
    command(s, 4, COARSE, now=52.12)               # the fine servo stays silent
    t = 52.12
    while s.sim.fault is None and t < 60.0:
        t = round(t + 0.2, 2)
        s.watch(now=t)
        s.on_timer(now=t)
    assert s.sim.fault == 'missing command for x_f y_f z_f a_f b_f c_f (no answer to step 4 within 2 s)'
    assert t == 54.32                              # the first call more than 2 s after step 4 went out


def test_paced_mode_a_slip_does_not_count_toward_an_axis_s_silence(make):
    """The periods hw_sim slipped sent no state: an axis's silence counts without them."""
    s, io = make(PacedSession, real_time_factor=0.1, command_timeout=0.05)      # 1 ms per step
    command(s, 0, now=0.0)
    s.on_timer(now=0.001)
    command(s, 1, now=0.0015)                      # the last commands
    s.on_timer(now=0.002)
    s.on_timer(now=0.0405)                         # 38.5 ms without running
    slip = s.overruns * 0.001
    assert s.sim.fault is None and slip >= 0.037
    k = 41
    while s.sim.fault is None and k < 200:         # every servo silent from now on, a call each 1 ms
        s.on_timer(now=k * 0.001)
        k += 1
    assert s.sim.fault.startswith('missing command for x_c')
    # the first call more than 50 ms of hw_sim running after the last commands
    assert (k - 2) * 0.001 <= 0.0015 + slip + 0.05 < (k - 1) * 0.001


def test_a_recorder_lost_by_its_liveliness_releases_the_hold_and_a_new_one_holds_again(make):
    s, io = make(recorder_window=3)
    run_to(s, 4)
    s.on_progress(*stamp(0), now=1.0)
    run_to(s, 10, now=1.0)
    assert s.step == 4                            # held for the recorder
    io.take()
    s.recorder_alive(True, now=1.5)               # alive: nothing changes
    assert io.take() == [] and s.step == 4
    s.recorder_alive(False, now=2.0)
    assert io.take() == [('info', 'recorder lost (its liveliness lease ran out): no longer holding for it'),
                         ('state', 5)]
    assert s.gate.lost == 1 and s.status(2.0).values['recorder_step'] == ''
    run_to(s, 20, now=2.0)
    assert s.step == 20                           # no hold without a recorder
    s.on_progress(*stamp(19), now=3.0)            # a recorder back: holds again from its report
    run_to(s, 30, now=3.0)
    assert s.step == 23                           # 23 - 19 > the window of 3
    s.recorder_alive(False, now=4.0)
    s.recorder_alive(False, now=4.1)              # counted once per loss
    assert s.gate.lost == 2


def test_finite_commands_whose_sum_leaves_the_float_range_are_not_taken_for_non_finite(make):
    """1e308 + 1e308 overflows a sum, yet both are finite: a command for a step ahead is
    refused as such (no fault); a NaN among them still faults, naming its axis."""
    s, io = make()
    io.take()
    command(s, 5, ('x_c', 'y_c'), [1e308, 1e308])
    assert io.take() == [('refused', 'command for step 5 while at step 0')] and s.sim.fault is None
    command(s, 0, ('x_c', 'y_c'), [1e308, math.nan])
    assert io.take()[0] == ('fault', 'non-finite command for y_c')


def test_a_recorder_that_has_written_nothing_holds_step_0_until_it_has_state_0(make):
    """A recorder reports the stamp of step -1 at start: hw_sim, its subscribers all there,
    stays at step 0 (re-sending it) until the recorder reports state 0 written."""
    s, io = make(min_subscribers=1, recorder_window=3)
    io.take()
    io.subscribers = 1
    s.on_progress(-1, 999_900_000, 0.0)          # step -1: a recorder is here, nothing written
    command(s, 0)
    assert s.step == 0
    s.on_timer(0.5)                               # re-sent while held
    assert s.step == 0 and ('state', 0) in io.take()
    s.on_progress(0, 0, 0.6)                      # state 0 is in the bag
    assert s.step == 1


def test_waiting_for_a_recorder_holds_step_0_until_one_reports_whoever_else_subscribes(make):
    """bringup --record: the state subscribers counted for min_subscribers may include one
    that is not the recorder's (the trajectory node's reader of the first state, dropped
    after it: run137's bag lacked states 0-310); the recorder's first report is waited for."""
    s, io = make(min_subscribers=1, recorder_window=3, wait_for_recorder=True)
    io.take()
    io.subscribers = 1                            # enough readers, none of them the recorder's
    command(s, 0)
    s.on_timer(0.5)
    assert s.step == 0 and ('state', 0) in io.take()      # held, state 0 re-sent
    s.on_progress(-1, 999_900_000, 0.6)           # the recorder is here, nothing written yet
    assert s.step == 0
    s.on_progress(0, 0, 0.7)                      # state 0 is in the bag
    assert s.step == 1


def test_a_recorder_lost_after_its_first_report_releases_the_wait_for_it(make):
    s, io = make(min_subscribers=1, recorder_window=3, wait_for_recorder=True)
    io.subscribers = 1
    s.on_progress(-1, 999_900_000, 0.1)
    command(s, 0, now=0.2)
    assert s.step == 0
    s.recorder_alive(False, 0.3)
    assert s.step == 1                            # the session goes on without a recording


def test_paced_mode_counts_nothing_before_the_graph_is_ready(make):
    s, _ = make(PacedSession, real_time_factor=0.1)          # 1 ms per step of wall time
    command(s, 0, COARSE)
    s.on_timer(now=0.001)
    s.on_timer(now=0.0045)                         # 2 periods slipped, but not ready: not counted
    assert s.step == 2 and not s.ready
    assert s.missed_deadlines == 0 and s.overruns == 0 and s.step_latency.count == 0


def test_paced_mode_steps_when_due_and_slips_when_hw_sim_itself_is_late(make, micromill):
    """A step at each due time; a timer call more than a period late takes one step (the
    controllers see every state), counts the periods slipped and shifts the schedule by them."""
    s, io = make(PacedSession, real_time_factor=0.1)          # 1 ms per step
    reference = MachineSimulator(micromill)
    first = [1e-3, -1e-3, 2e-3, 1e-4, 0.0, -1e-4, 1e-3, 0.0, 5e-4]
    command(s, 0, AXES, first, now=0.0004)
    s.on_timer(now=0.0009)                         # before step 1 is due: nothing happens
    assert s.step == 0
    s.on_timer(now=0.001)
    reference.step(first)
    assert s.ready and s.step == 1
    io.take()
    command(s, 1, COARSE, [2e-3, 0.0, -2e-3], now=0.0012)
    s.on_timer(now=0.0042)                         # step 2 was due at 2 ms: 2 periods slipped
    reference.step([2e-3, 0.0, -2e-3] + first[3:])
    assert s.step == 2 and s.overruns == 2 and s.missed_deadlines == 6     # the fine axes at step 1
    assert s.sim.measurement == reference.measurement and io.states() == [2]
    s.on_timer(now=0.0049)                         # step 2 now counts as due at 4 ms (the timer's phase kept)
    assert s.step == 2
    s.on_timer(now=0.0050)
    assert s.step == 3 and s.overruns == 2
    status = s.status(0.0050).values
    assert status['overruns'] == 2 and status['tick_lateness_count'] == 3
    # the tick lateness: step 2 due at 2 ms, called at 4.2 ms
    assert float(status['tick_lateness_max']) == pytest.approx(0.0022)


def test_paced_mode_measures_each_step_latency(make):
    """State out to the step's last command in; a step missed is counted with what it had
    waited at its deadline (a lower bound)."""
    s, _ = make(PacedSession, real_time_factor=0.1)          # 1 ms per step
    command(s, 0, now=0.0003)
    s.on_timer(now=0.001)                          # ready with step 0's answers: not timed
    assert s.ready and s.step_latency.count == 0
    command(s, 1, COARSE, now=0.0011)
    command(s, 1, FINE, now=0.0014)                # complete 0.4 ms after the state went out
    command(s, 1, FINE, now=0.0016)                # a repeat changes nothing
    s.on_timer(now=0.002)
    command(s, 2, COARSE, now=0.0021)              # the fine axes never answer step 2
    s.on_timer(now=0.0030)
    assert s.step_latency.count == 2 and s.missed_deadlines == 6
    assert s.step_latency.maximum == pytest.approx(0.001)
    assert 0.0004 <= s.step_latency.percentile(50) <= 0.0004 * 1.02
    assert s.step_latency.percentile(100) == pytest.approx(0.001)


def test_paced_mode_faults_when_hw_sim_itself_stalls(make):
    s, io = make(PacedSession, real_time_factor=0.1, command_timeout=0.5)
    command(s, 0)
    s.on_timer(now=0.001)
    io.take()
    s.on_timer(now=0.9)                            # 0.9 s without a call: 898 periods slipped
    events = io.take()
    assert events[0] == ('fault', 'hw_sim stalled: 0.9 s behind the wall clock (its process did not run: '
                                  'stopped or starved; limit command_timeout 0.5 s)')
    assert s.step == 2 and s.overruns == 898 and s.sim.fault is not None
    s.on_timer(now=0.901)                          # the schedule starts again from the stall
    assert s.step == 3


def test_paced_mode_faults_on_an_axis_silent_for_the_command_timeout(make):
    """A drive's watchdog: held commands are fine for a while, an axis whose controller has
    said nothing for command_timeout faults the machine, named."""
    s, io = make(PacedSession, real_time_factor=0.1, command_timeout=0.05)      # 1 ms per step
    command(s, 0, now=0.0)
    k = 1
    while s.sim.fault is None and k < 200:
        s.on_timer(now=k * 0.001)
        command(s, s.step, COARSE, now=k * 0.001)                   # the fine servo is silent
        k += 1
    assert s.sim.fault == 'missing command for x_f y_f z_f a_f b_f c_f (none within 0.05 s)'
    assert k == 52                                 # the first tick more than 50 ms after step 0's answers


def test_paced_mode_watchdog_counts_late_commands_as_alive(make):
    """A controller always a little late (its commands for a step already taken) misses
    every deadline, each late command counted stale, but is alive: no fault."""
    s, _ = make(PacedSession, real_time_factor=0.1, command_timeout=0.05)      # 1 ms per step
    command(s, 0, now=0.0)
    for k in range(1, 200):
        s.on_timer(now=k * 0.001)
        command(s, s.step - 1, now=k * 0.001 + 0.0002)                  # answers the step before
    assert s.sim.fault is None and s.missed_deadlines == 9 * 198       # step 0 was answered in time
    assert s.lockstep.stats.stale == 199 and s.status(0.2).values['stale_commands'] == 199


def test_a_reset_in_paced_mode_re_arms_the_watchdog(make):
    s, io = make(PacedSession, real_time_factor=0.1, command_timeout=0.05)
    command(s, 0, now=0.0)
    k = 1
    while s.sim.fault is None:                     # every servo silent: a fault after 50 ms
        s.on_timer(now=k * 0.001)
        k += 1
    assert k == 52 and s.sim.fault.startswith('missing command for x_c')
    s.reset(now=0.052)
    for t in (0.053, 0.054, 0.055):                # the servos come back from the third step on
        s.on_timer(now=t)
    command(s, s.step, now=0.0555)
    s.on_timer(now=0.056)
    assert s.sim.fault is None


def test_paced_mode_does_not_fault_on_a_slow_start(make):
    """In one process hw_sim's timer starts before the other nodes are built: a first call
    long after the start only shifts the schedule while the graph is not ready."""
    s, io = make(PacedSession, real_time_factor=0.1, command_timeout=0.5)
    s.on_timer(now=6.0)
    assert s.step == 1 and s.sim.fault is None and s.overruns == 0
    s.on_timer(now=6.0009)
    assert s.step == 1
    s.on_timer(now=6.001)
    assert s.step == 2


def test_the_paced_schedule_runs_on_the_timer_s_whole_nanoseconds(make):
    """rclpy truncates a timer's period to whole ns; the schedule uses the same period, so
    it keeps the timer's phase however long it runs."""
    s, _ = make(PacedSession, real_time_factor=0.3)                         # 1e-4 / 0.3 s
    assert s.pacer.period == 333_333e-9
    assert s.pacer.due(1e6 * 333_333e-9) == 1_000_000
