"""The fault model (README "Faults") for the compensation node, which carries the trajectory
node's reference on to the servos: stopped (SIGSTOP, past its liveliness lease and the
confirmation) or killed mid-goal, the servos run out of reference and hold (hw_sim does not
fault), the trajectory node aborts the goal naming it and refuses goals until it is back;
continued (SIGCONT) or started again, a new goal succeeds. Real nodes over real DDS, each in
its own process (the graph of test_faults.py with compensation in the chain)."""
import signal
import time

import numpy as np
import pytest

from limit_checks import LINEAR_STILL, ROTARY_STILL
from machine_ctrl import contract
from machine_ctrl.ros.graph import default_graph
from test_faults import GUARD, TERMINAL, graph_client, running_graph, slow_goal


def specs(machine):
    model = str(machine.simulation.error_map_path(machine.yaml_path))
    return {spec.name: spec for spec in default_graph(machine, contour=None, compensation_model=model)}


@pytest.fixture(scope='module')
def graph(micromill, ros_env, tmp_path_factory):
    with running_graph(specs(micromill), ros_env, tmp_path_factory.mktemp('logs')) as supervisor:
        yield supervisor


@pytest.fixture(scope='module')
def client(micromill, graph, ros_env):
    with graph_client(micromill, graph, specs(micromill), ros_env, 'faults_compensation_client') as c:
        yield c


FOLLOWERS = ('servo_coarse', 'servo_fine', 'dual_stage')     # the nodes that follow /reference


def test_a_stopped_or_killed_compensation_aborts_the_goal_naming_it_the_servos_hold_and_goals_wait_for_it(
        micromill, graph, client):
    x = micromill.axis_names.index('x_c')
    rotary = np.array([a.unit == 'rad' for a in micromill.axes])
    lost = (f'compensation lost: no sign of life within its {contract.LIVELINESS_LEASE:g} s liveliness lease '
            '(killed, stopped or hung); '
            'the reference does not reach the servos')

    def lost_under_way(fault):
        """`fault` (SIGSTOP or SIGKILL) sent to the compensation node during a goal: the goal
        aborted naming it, the status too, the servos out of reference and holding (no
        fault), a new goal refused while it is lost."""
        stamp, target = slow_goal(client, seconds=3.0)
        client.wait_goal(stamp, ('executing',), graph.check)
        underruns = int(client.diag('servo_coarse', 'reference_underruns', '0'))
        fault()
        _, state, reason = client.wait_goal(stamp, TERMINAL, graph.check)
        assert (state, reason) == ('aborted', lost)
        client.wait(lambda: client.status().get('reference_lost') == lost, 'the status naming it', GUARD,
                    graph.check)
        # the servos run out of reference while moving and hold its last row, their stream broken
        # (model/reference.py ReferenceBuffer): the machine stands, no fault
        client.wait(lambda: int(client.diag('servo_coarse', 'reference_underruns', '0')) > underruns,
                    'an underrun', GUARD, graph.check)
        for node in FOLLOWERS:
            client.wait(lambda n=node: client.diag(n, 'reference_broken_step', '') != '', f'{node} holding',
                        GUARD, graph.check)
        assert client.diag('hw_sim', 'fault') == '' and abs(client.truth[x] - target) > 0.2e-3
        refused, _ = slow_goal(client, distance=-0.5e-3, seconds=0.0)
        _, state, reason = client.wait_goal(refused, TERMINAL, graph.check)
        assert (state, reason) == ('aborted', f'joint goal: {lost}')      # refused while it is lost
        # where the servos hold, and the step each follower's stream broke at (for a failure's
        # report: the return holds the row before the break only when they agree)
        return client.truth.copy(), {node: client.diag(node, 'reference_broken_step') for node in FOLLOWERS}

    def back(held, breaks):
        """Goals accepted again; the servos took the stream up again (rows that were on their
        way before the break were refused: model/reference.py ReferenceBuffer); the machine has
        stayed where the servos held, with no goal (0.5 s of sim time after the return): every
        axis within its noise-driven jitter at rest; and a new goal succeeds."""
        client.wait(lambda: client.status().get('reference_lost') == '', 'the compensation node back', GUARD,
                    graph.check)
        # it forwards again: its chunk count grows after a first report from after the return, from the
        # one writer its input reader is matched with (a deaf one: README "Faults", shared memory)
        returned = time.monotonic()
        client.wait(lambda: client.heard.get('compensation', 0) > returned, 'a compensation report', GUARD, graph.check)
        chunks = int(client.diag('compensation', 'chunks'))
        client.wait(lambda: int(client.diag('compensation', 'chunks')) > chunks
                    and client.diag('compensation', 'input_writers') == '1', 'compensation forwarding', GUARD,
                    graph.check)
        step = int(client.diag('hw_sim', 'step') or 0) + round(0.5 / micromill.control_period)
        client.wait(lambda: int(client.diag('hw_sim', 'step') or 0) > step, '0.5 s of sim time', GUARD, graph.check)
        moved = np.abs(client.truth - held)
        assert moved[~rotary].max() < LINEAR_STILL and moved[rotary].max() < ROTARY_STILL, (moved, breaks)  # none moved
        for node in FOLLOWERS:              # a report of a step after the return: following again
            client.wait(lambda n=node: int(client.diag(n, 'answered_step', '0') or 0) > step
                        and client.diag(n, 'reference_broken_step', '?') == '', f'{node} following again',
                        GUARD, graph.check)
        stamp, target = slow_goal(client, distance=-0.5e-3, seconds=0.0)
        _, state, reason = client.wait_goal(stamp, TERMINAL, graph.check)
        assert state == 'succeeded', reason
        client.wait(lambda: abs(client.truth[x] - target) < 1e-6, 'x_c at the new goal', GUARD, graph.check)

    # stopped: its liveliness lease runs out (the abort waits for that: no time is assumed)
    held, breaks = lost_under_way(lambda: graph['compensation'].signal_group(signal.SIGSTOP))
    graph['compensation'].signal_group(signal.SIGCONT)
    back(held, breaks)                                  # its liveliness asserted again: goals accepted

    def kill():
        graph['compensation'].stopping = True
        graph['compensation'].signal_group(signal.SIGKILL)
        assert graph.wait('compensation', GUARD) == -signal.SIGKILL
    held, breaks = lost_under_way(kill)
    graph.start('compensation', specs(micromill)['compensation'].argv())
    graph.wait_for_line('compensation', 'ready', GUARD)
    back(held, breaks)
    graph.check()
