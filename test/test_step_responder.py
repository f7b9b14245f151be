"""The per-step answerer of the servo and dual-stage nodes: one answer per step, re-sends
answered from cache, the input timeout counted from a step's first arrival (hw_sim re-sends
while it waits), stray future stamps refused. The rules (machine_ctrl.control.stepping) run
on fake wall time passed in; the ROS wrapper (node_common.StepResponder) is checked to
publish through them."""
import pytest

from machine_ctrl.control.stepping import StepAnswerer
from machine_ctrl.model.errors import InvalidMessage


@pytest.fixture
def answerer():
    inputs = {'ready': set(), 'streaming': True, 'computed': [], 'sent': []}

    def compute(step, msg):
        inputs['computed'].append(step)
        return f'answer {step}'
    a = StepAnswerer(inputs['sent'].append, lambda step: step in inputs['ready'], compute, 0.3,
                     lambda: inputs['streaming'])
    return a, inputs


def test_each_step_is_computed_once_and_resends_get_the_cached_answer(answerer):
    a, inputs = answerer
    inputs['ready'].add(0)
    a.on_state(0, 'state 0', now=0.0)
    a.on_state(0, 'state 0 again', now=0.2)
    assert inputs['computed'] == [0] and inputs['sent'] == ['answer 0', 'answer 0']
    assert a.answered_step == 0 and not a.waiting


def test_a_step_counts_as_answered_only_once_its_answer_went_out(answerer):
    """has_answered: what a node's per-step input streams use to drop readings of steps
    already answered (hw_sim's re-sends) — step 0 is not answered before its answer."""
    a, inputs = answerer
    assert not a.has_answered(0)
    a.on_state(0, 'state 0', now=0.0)
    assert not a.has_answered(0)                     # waiting for its inputs
    inputs['ready'].add(0)
    a.poke()
    assert a.has_answered(0) and not a.has_answered(1)


def test_older_stamps_are_ignored(answerer):
    a, inputs = answerer
    inputs['ready'].update(range(5))
    for step in (0, 1, 2):
        a.on_state(step, f'state {step}', now=0.0)
    a.on_state(1, 'state 1 late', now=0.1)
    assert inputs['computed'] == [0, 1, 2] and inputs['sent'] == ['answer 0', 'answer 1', 'answer 2']


def test_timeout_counts_from_the_first_arrival_despite_resends(answerer):
    a, inputs = answerer
    a.on_state(5, 'state 5', now=10.0)           # inputs of step 5 missing
    for t in (10.1, 10.2, 10.25):                # hw_sim re-sends; 0.3 s not yet passed
        a.on_state(5, 'state 5', now=t)
        a.on_timer(now=t)
    assert inputs['computed'] == [] and a.waiting
    a.on_state(5, 'state 5', now=10.35)
    a.on_timer(now=10.35)                        # 0.35 s after the first arrival
    assert inputs['computed'] == [5] and inputs['sent'] == ['answer 5'] and not a.waiting


def test_no_timeout_before_the_stream_ever_started(answerer):
    a, inputs = answerer
    inputs['streaming'] = False
    a.on_state(3, 'state 3', now=0.0)
    a.on_timer(now=100.0)
    assert inputs['computed'] == [] and a.waiting
    inputs['ready'].add(3)
    a.poke()
    assert inputs['computed'] == [3]


def test_no_answer_when_compute_gives_none(answerer):
    a, inputs = answerer
    a.compute = lambda step, msg: None
    inputs['ready'].add(0)
    a.on_state(0, 'state 0', now=0.0)
    assert inputs['sent'] == [] and a.answered is None and not a.waiting


def test_a_stray_future_stamp_is_refused_once_and_the_real_steps_go_on(answerer):
    a, inputs = answerer
    inputs['ready'].update(range(10))
    a.on_state(0, 'state 0', now=0.0)
    with pytest.raises(InvalidMessage, match='state of step 500 skips ahead of step 1'):
        a.on_state(500, 'stray', now=0.0)
    a.on_state(1, 'state 1', now=0.0)
    a.on_state(2, 'state 2', now=0.0)
    assert inputs['computed'] == [0, 1, 2]


def test_a_real_jump_is_taken_when_re_sent(answerer):
    a, inputs = answerer
    inputs['ready'].update([0, 7])
    a.on_state(0, 'state 0', now=0.0)
    with pytest.raises(InvalidMessage, match='skips ahead'):
        a.on_state(7, 'state 7', now=0.0)
    a.on_state(7, 'state 7 again', now=0.1)      # hw_sim re-sends what it waits on
    assert inputs['computed'] == [0, 7]


def test_a_jump_confirmed_by_its_successor_is_taken_there(answerer):
    """States lost on the way (paced mode, a queue overrun): the state after the gap is
    refused, its successor confirms the gap and is answered."""
    a, inputs = answerer
    inputs['ready'].update(range(20))
    a.on_state(0, 'state 0', now=0.0)
    with pytest.raises(InvalidMessage, match='skips ahead'):
        a.on_state(7, 'state 7', now=0.0)
    a.on_state(8, 'state 8', now=0.0)
    a.on_state(9, 'state 9', now=0.0)
    assert inputs['computed'] == [0, 8, 9]
    with pytest.raises(InvalidMessage, match='skips ahead'):
        a.on_state(15, 'state 15', now=0.0)
    with pytest.raises(InvalidMessage, match='skips ahead'):      # neither 15 again nor 16: refused too
        a.on_state(17, 'state 17', now=0.0)
    a.on_state(10, 'state 10', now=0.0)
    assert inputs['computed'] == [0, 8, 9, 10]


def test_a_stray_stream_interleaved_with_the_real_steps_is_refused(answerer):
    """Another hw_sim's states (a second graph in the domain): a real step between two of
    them clears the candidate, so its successor is a new stray, refused again. (Two of them
    back to back would be taken: the rule guards against single strays, README.)"""
    a, inputs = answerer
    inputs['ready'].update(range(10))
    a.on_state(0, 'state 0', now=0.0)
    for real, stray in ((1, 500), (2, 501), (3, 502)):
        with pytest.raises(InvalidMessage, match='skips ahead'):
            a.on_state(stray, 'stray', now=0.0)
        a.on_state(real, f'state {real}', now=0.0)
    assert inputs['computed'] == [0, 1, 2, 3]


def test_states_arriving_while_one_waits_are_not_skips(answerer):
    a, inputs = answerer
    a.on_state(0, 'state 0', now=0.0)            # inputs of 0 missing: pending
    a.on_state(1, 'state 1', now=0.0)            # paced mode: hw_sim went on
    a.on_state(2, 'state 2', now=0.0)
    inputs['ready'].add(2)
    a.poke()
    assert inputs['computed'] == [2]


class FakePublisher:
    def __init__(self):
        self.sent = []

    def publish(self, msg):
        self.sent.append(msg)


def test_the_ros_responder_publishes_through_the_rules(ros_node):
    from machine_ctrl.ros.node_common import StepResponder
    ready = set()
    pub = FakePublisher()
    r = StepResponder(ros_node('responder'), pub, lambda step: step in ready, lambda step, msg: f'answer {step}',
                      0.3, lambda: True)
    r.on_state(0, 'state 0')
    assert r.waiting and pub.sent == []
    ready.add(0)
    r.poke()
    r.on_state(0, 'state 0 again')
    assert pub.sent == ['answer 0', 'answer 0'] and r.answered_step == 0 and not r.waiting
    with pytest.raises(InvalidMessage, match='skips ahead'):
        r.on_state(9, 'stray')
