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
    from machine_ctrl.node_common import StepResponder
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
