"""StepResponder (node_common): one answer per step, re-sends answered from cache, and the
input timeout counted from a step's first arrival (hw_sim re-sends while it waits)."""
import time

import pytest


class FakePublisher:
    def __init__(self):
        self.sent = []

    def publish(self, msg):
        self.sent.append(msg)


@pytest.fixture
def responder(ros_node):
    from machine_ctrl.ros.node_common import StepResponder
    inputs = {'ready': set(), 'streaming': True, 'computed': []}

    def compute(step, msg):
        inputs['computed'].append(step)
        return f'answer {step}'
    pub = FakePublisher()
    r = StepResponder(ros_node('responder'), pub, lambda step: step in inputs['ready'], compute, 0.3,
                      lambda: inputs['streaming'])
    return r, pub, inputs


def test_each_step_is_computed_once_and_resends_get_the_cached_answer(responder):
    r, pub, inputs = responder
    inputs['ready'].add(0)
    r.on_state(0, 'state 0')
    r.on_state(0, 'state 0 again')
    assert inputs['computed'] == [0] and pub.sent == ['answer 0', 'answer 0']


def test_timeout_counts_from_the_first_arrival_despite_resends(responder):
    r, pub, inputs = responder
    r.on_state(5, 'state 5')                 # inputs of step 5 missing
    for _ in range(6):                       # hw_sim re-sends every 0.1 s
        time.sleep(0.1)
        r.on_state(5, 'state 5')
        r._on_timer()
    assert inputs['computed'] == [5]         # gave up after 0.3 s although re-sent


def test_no_timeout_before_the_stream_ever_started(responder):
    r, pub, inputs = responder
    inputs['streaming'] = False
    r.on_state(3, 'state 3')
    time.sleep(0.4)
    r._on_timer()
    assert inputs['computed'] == []
    inputs['ready'].add(3)
    r.poke()
    assert inputs['computed'] == [3]


def test_a_stray_future_stamp_is_refused_once_and_the_real_steps_go_on(responder):
    from machine_ctrl.ros.messages import InvalidMessage
    r, pub, inputs = responder
    inputs['ready'].update(range(10))
    r.on_state(0, 'state 0')
    with pytest.raises(InvalidMessage, match='skips ahead'):
        r.on_state(500, 'stray')
    r.on_state(1, 'state 1')
    r.on_state(2, 'state 2')
    assert inputs['computed'] == [0, 1, 2]


def test_a_real_jump_is_taken_when_re_sent(responder):
    r, pub, inputs = responder
    inputs['ready'].update([0, 7])
    r.on_state(0, 'state 0')
    with pytest.raises(Exception, match='skips ahead'):
        r.on_state(7, 'state 7')
    r.on_state(7, 'state 7 again')              # hw_sim re-sends what it waits on
    assert inputs['computed'] == [0, 7]


def test_states_arriving_while_one_waits_are_not_skips(responder):
    r, pub, inputs = responder
    r.on_state(0, 'state 0')                    # inputs of 0 missing: pending
    r.on_state(1, 'state 1')                    # paced mode: hw_sim went on
    r.on_state(2, 'state 2')
    inputs['ready'].add(2)
    r.poke()
    assert inputs['computed'] == [2]
