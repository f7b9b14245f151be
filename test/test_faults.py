"""The fault model (README "Faults"): each node of the running graph lost (SIGKILL) or stalled
(SIGSTOP, then SIGCONT) mid-goal, real nodes over real DDS, each in its own process. What the
others do — hw_sim faults naming the axes, the goal aborted with the reason, `machine-ctrl
move` exits 1 with one line, the non-control contour_error changes nothing — then restart
and /hw_sim/reset, after which nothing moves without a new goal.

One graph for the module (hw_sim, servo_coarse, servo_fine, dual_stage, trajectory,
contour_error); a killed node is started again by the test, and the tests that kill hw_sim
come last. Every wait is on a condition (a goal state, a fault, a process exit, a line);
GUARD only bounds a failure.
"""
import contextlib
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from machine_ctrl import contract
from machine_ctrl.app.client import MachineClient, Timeout
from machine_ctrl.app.processes import Supervisor
from machine_ctrl.parameters import HW_SIM
from machine_ctrl.ros.graph import default_graph
from ros_fixtures import private_context

GUARD = 120.0          # s: a failure guard only, never a measured time (2 busy cores)
COMMAND_TIMEOUT = HW_SIM.spec('command_timeout').default      # s: the graph's (its default)
TERMINAL = ('succeeded', 'canceled', 'aborted')


def specs(machine):
    return {spec.name: spec for spec in default_graph(machine, contour=None, contour_error=True)}


class Client(MachineClient):
    """The command API plus what the test observes: every node's newest /diagnostics values
    and the true axis positions (hw_sim's ground truth, decimated)."""

    def __init__(self, node, machine, graph=None):
        from diagnostic_msgs.msg import DiagnosticArray
        from sensor_msgs.msg import JointState
        self.diagnostics, self.truth = {}, None
        self.heard = {}                 # node name -> wall time (monotonic) of its newest /diagnostics
        self.graph = graph              # the Supervisor, for the stacks of a timeout's report
        node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, self.on_diagnostics, 100)
        node.create_subscription(JointState, contract.TRUE_JOINT_STATES.name, self.on_truth, 10)
        super().__init__(node, machine)

    def on_diagnostics(self, msg):
        for status in msg.status:
            self.diagnostics[status.name] = {kv.key: kv.value for kv in status.values}
            self.heard[status.name] = time.monotonic()

    def on_truth(self, msg):
        self.truth = np.array(msg.position)

    def wait(self, predicate, what: str, timeout: float = 120.0, check=None) -> None:
        """MachineClient.wait; a timeout also tells what hw_sim, the step nodes and the
        compensation node said last on /diagnostics (the held step, the step answered, what each
        waits for, the fault, the chunks forwarded) and how long ago; and, with the graph, every
        thread's stack of each of them (a node that went quiet: hung, or deaf)."""
        try:
            super().wait(predicate, what, timeout, check)
        except Timeout as exc:
            now, names = time.monotonic(), ('hw_sim', *STEP_NODES, 'compensation')
            said = {name: {'heard_s_ago': round(now - self.heard[name], 1),
                           **{key: self.diag(name, key) for key in ('step', 'answered_step', 'waiting_for', 'fault',
                                                                     'buffered_steps', 'refused_reference_rows',
                                                                     'chunks', 'input_writers', 'rejected_chunks',
                                                                     'last_rejection') if self.diag(name, key)}}
                    for name in names if name in self.heard}
            stacks = '' if self.graph is None else ''.join(
                f'\n--- stacks of {name}:\n' + '\n'.join(self.graph.stacks(name))
                for name in names if name in self.graph.children and self.graph[name].running())
            raise Timeout(f'{exc}; diagnostics {said}{stacks}') from None

    def diag(self, node, key, default=''):
        return self.diagnostics.get(node, {}).get(key, default)

    def goal(self, stamp):
        """(id, newest state, reason) of the goal sent with `stamp` (id None before it shows)."""
        goal_id = self.goal_of(stamp)
        if goal_id is None:
            return None, '', ''
        return goal_id, self.goal_state(goal_id), self.goal_entries.get(goal_id, {}).get('reason', '')

    def wait_goal(self, stamp, states, check):
        """Wait until the goal is in one of `states`; an ended goal also until its /diagnostics
        entry (the reason) says so: it travels on another topic than the goal status, so it
        may come after it."""
        def reached():
            goal_id, state, _ = self.goal(stamp)
            return state in states and (state not in TERMINAL
                                        or self.goal_entries.get(goal_id, {}).get('status') == state)
        self.wait(reached, f'the goal {states}', GUARD, check)
        return self.goal(stamp)


@contextlib.contextmanager
def running_graph(node_specs, ros_env, log_dir):
    """Every node of `node_specs` (name -> NodeSpec) in its own process, stopped on leaving."""
    with Supervisor(ros_env, log_dir=log_dir, stop_timeout=3.0) as supervisor:
        supervisor.start_nodes(node_specs.values())
        yield supervisor


@contextlib.contextmanager
def graph_client(machine, graph, node_specs, ros_env, name):
    """The test's Client, once the graph is ready, idle, and every node of `node_specs`
    reports on /diagnostics."""
    import rclpy
    with private_context(ros_env) as context:
        node = rclpy.create_node(name, context=context)
        c = Client(node, machine, graph)
        try:
            c.wait_ready(GUARD, graph.check)
            c.wait(lambda: c.status().get('state') == 'idle' and c.truth is not None
                   and c.trajectory_alive and all(n in c.diagnostics for n in node_specs),
                   'the graph running', GUARD, graph.check)
            c.wait_listening(GUARD, graph.check, c.command_publishers)   # no command before the match
            yield c
        finally:
            c.close()
            node.destroy_node()


@pytest.fixture(scope='module')
def graph(micromill, ros_env, tmp_path_factory):
    with running_graph(specs(micromill), ros_env, tmp_path_factory.mktemp('logs')) as supervisor:
        yield supervisor


@pytest.fixture(scope='module')
def client(micromill, graph, ros_env):
    with graph_client(micromill, graph, specs(micromill), ros_env, 'faults_client') as c:
        yield c


@pytest.fixture(autouse=True)
def recovered(micromill, graph, client):
    """Each test starts from a whole graph at rest: what a failed test left behind (a node
    stopped or gone, a goal under way, the override low, the machine faulted) is undone
    first, so that one failure does not fail the tests after it."""
    for name in specs(micromill):
        if graph[name].running():
            graph[name].signal_group(signal.SIGCONT)
        else:
            graph[name].stopping = True
            restart(graph, micromill, name)
    # streaming: a trajectory node just restarted refuses goals until it has heard a state
    # (run48: a goal sent right after the restart was refused, "no joint_states")
    client.wait(lambda: client.trajectory_alive and client.status().get('state') is not None
                and client.status().get('streamed_to_step', '') != '', 'the trajectory node streaming', GUARD,
                graph.check)
    if client.status().get('state') not in ('idle', 'fault'):
        client.call(contract.STOP.name)
    if client.status().get('feed_override_setting') != '1.0':
        client.set_feed_override(1.0)
        client.wait(lambda: client.status().get('feed_override_setting') == '1.0', 'the override', GUARD,
                    graph.check)
    client.wait(lambda: client.status().get('state') in ('idle', 'fault'), 'idle or faulted', GUARD, graph.check)
    if client.status().get('state') == 'fault' or client.diag('hw_sim', 'fault'):
        reset(client, graph)


def kill(graph, name):
    """SIGKILL node `name` (its process group) and wait until it is gone."""
    graph[name].stopping = True                   # its end is expected: graph.check() stays quiet
    graph[name].signal_group(signal.SIGKILL)
    assert graph.wait(name, GUARD) == -signal.SIGKILL


def restart(graph, micromill, name):
    spec = specs(micromill)[name]
    graph.start(name, spec.argv())
    graph.wait_for_line(name, 'ready', GUARD)


def slow_goal(client, axis='x_c', distance=1e-3, seconds=3.0):
    """A joint goal on `axis` that takes `seconds` of sim time: long enough to fail under way."""
    here = client.truth[client.machine.axis_names.index(axis)]
    return client.send_goal([axis], [[here + distance]], [seconds]), here + distance


def succeeded(client, stamp, graph):
    _, state, reason = client.wait_goal(stamp, TERMINAL, graph.check)
    assert state == 'succeeded', reason
    return True


def faulted(client, graph):
    """The trajectory status says fault (it travels on its own topic: it may come after the
    goal status and the /diagnostics entry that told the test)."""
    client.wait(lambda: client.status().get('state') == 'fault', 'the status saying fault', GUARD, graph.check)


def answering(client, node):
    """`node` answers the step hw_sim holds (it is back in lock-step)."""
    return lambda: client.diag(node, 'answered_step') == client.diag('hw_sim', 'step') != ''


STEP_NODES = ('servo_coarse', 'servo_fine', 'dual_stage')
RESETS = 3


def reset(client, graph):
    """/hw_sim/reset once every step node answers the step hw_sim holds, until the trajectory
    node is idle and the machine steps. A reset restarts the held step's command_timeout:
    nodes still catching up after a stall can miss it (seen on a loaded machine), and hw_sim
    faults again naming them — then, as an operator would, the reset is repeated once they
    answer (README "Faults"), at most RESETS times."""
    for _ in range(RESETS):
        # a healthy hw_sim steps on (no held step to wait for: its diagnostics and the nodes'
        # come at different steps); a faulted one holds its step until every node answers it
        client.wait(lambda: client.diag('hw_sim', 'step') != '' and (not client.diag('hw_sim', 'fault') or all(
            client.diag(n, 'answered_step') == client.diag('hw_sim', 'step') for n in STEP_NODES)),
            'every step node answering the held step', GUARD, graph.check)
        assert client.call(contract.RESET.name)[0]
        client.wait(lambda: client.status().get('state') == 'idle' and client.diag('hw_sim', 'fault') == '',
                    'idle after the reset', GUARD, graph.check)
        step = int(client.diag('hw_sim', 'step'))
        client.wait(lambda: int(client.diag('hw_sim', 'step') or 0) > step + 1000 or client.diag('hw_sim', 'fault'),
                    'the machine stepping, or a fault', GUARD, graph.check)
        if not client.diag('hw_sim', 'fault'):
            break
    else:
        pytest.fail(f'hw_sim faulted after each of {RESETS} resets: {client.diag("hw_sim", "fault")}')


def reset_and_move(client, graph, axis='x_c', still=True):
    """:func:`reset`, then nothing has moved (`still`; else the stop of the aborted goal may
    still play out) and a new goal succeeds."""
    held = client.truth.copy()
    reset(client, graph)
    i = client.machine.axis_names.index(axis)
    assert not still or abs(client.truth[i] - held[i]) < 1e-6    # the aborted goal's axis: no goal, no motion
    stamp, target = slow_goal(client, axis, 10e-6 if axis.endswith('_f') else 0.5e-3, 0.0)
    assert succeeded(client, stamp, graph)

    client.wait(lambda: abs(client.truth[i] - target) < 2e-6, f'{axis} at its goal', GUARD, graph.check)


def move_cli(graph, ros_env, name, *goal):
    """`machine-ctrl move` as a process of its own, as a user runs it."""
    exe = str(Path(sys.executable).parent / 'machine-ctrl')
    graph.start(name, [exe, 'move', *goal, '--machine', 'micromill_9axis', '--timeout', '3600'])
    graph[name].stopping = True                   # it is meant to end


def slow_move_cli(client, graph, ros_env, name):
    """`machine-ctrl move` of x_c by 5 mm at feed override 0.02 (~50x longer: time to kill a
    node under way), followed until it is executing."""
    client.set_feed_override(0.02)
    client.wait(lambda: client.status().get('feed_override_setting') == '0.02', 'the override', GUARD, graph.check)
    move_cli(graph, ros_env, name, f'x_c={float(client.truth[0]) + 5e-3!r}')
    graph.wait_for_line(name, ': executing', GUARD)


# -- a non-control node: nothing stops -------------------------------------------------------

def test_contour_error_stalled_or_killed_does_not_stop_the_machine(micromill, graph, client):
    graph['contour_error'].signal_group(signal.SIGSTOP)
    stamp, _ = slow_goal(client, seconds=0.0)
    assert succeeded(client, stamp, graph)
    graph['contour_error'].signal_group(signal.SIGCONT)
    kill(graph, 'contour_error')
    stamp, _ = slow_goal(client, distance=-1e-3, seconds=0.0)
    assert succeeded(client, stamp, graph)
    assert client.diag('hw_sim', 'fault') == ''
    restart(graph, micromill, 'contour_error')
    graph.check()


# -- servos and dual stage: hw_sim faults naming the axes ----------------------------------

def test_a_stopped_servo_faults_hw_sim_naming_its_axes_and_aborts_the_goal(micromill, graph, client):
    axes = ' '.join(specs(micromill)['servo_coarse'].parameters['axes'])
    stamp, _ = slow_goal(client)
    client.wait_goal(stamp, ('executing',), graph.check)
    graph['servo_coarse'].signal_group(signal.SIGSTOP)
    _, state, reason = client.wait_goal(stamp, TERMINAL, graph.check)
    assert state == 'aborted' and f'machine faulted: missing command for {axes} ' in reason, reason
    client.wait(lambda: client.diag('hw_sim', 'fault') != '', 'hw_sim naming the fault', GUARD, graph.check)
    assert client.diag('hw_sim', 'fault') in reason
    held = client.truth.copy()
    graph['servo_coarse'].signal_group(signal.SIGCONT)
    client.wait(answering(client, 'servo_coarse'), 'the servo answering the held step', GUARD, graph.check)
    assert 'its process did not run for' in graph.wait_for_line('servo_coarse', 'did not run for', GUARD)
    faulted(client, graph)
    assert np.abs(client.truth - held).max() < 1e-9   # drives off: held
    reset_and_move(client, graph)


def stall_logged(graph, name, at_least):
    """The line of `name`'s output saying its process did not run for at least `at_least` s
    (StepResponder: printed to 0.1 s), or None: an earlier, shorter gap (a loaded machine)
    is not it."""
    for line in graph[name].tail(200):
        if 'its process did not run for ' in line:
            if float(line.split(' did not run for ')[1].split(' s')[0]) >= at_least - 0.1:
                return line
    return None


def test_a_killed_or_stopped_dual_stage_faults_hw_sim_naming_the_fine_axes_restart_or_cont_and_reset_recover(
        micromill, graph, client):
    fine = ' '.join(specs(micromill)['servo_fine'].parameters['axes'])
    stamp, _ = slow_goal(client, 'x_f', 20e-6, 3.0)
    client.wait_goal(stamp, ('executing',), graph.check)
    kill(graph, 'dual_stage')
    _, state, reason = client.wait_goal(stamp, TERMINAL, graph.check)
    assert state == 'aborted' and f'machine faulted: missing command for {fine} ' in reason, reason
    client.wait(lambda: 'dual_stage/offsets (none for step' in client.diag('servo_fine', 'waiting_for'),
                'servo_fine naming the offsets it lacks', GUARD, graph.check)
    assert client.diag('servo_fine', 'waiting_for').endswith(' matched)')      # the writers its reader has
    restart(graph, micromill, 'dual_stage')
    client.wait(answering(client, 'servo_fine'), 'servo_fine answering with the new offsets', GUARD, graph.check)
    reset_and_move(client, graph, 'x_f')

    # stopped (SIGSTOP) under way, then continued: the same fault, and its log tells the stall
    stamp, _ = slow_goal(client, 'x_f', -20e-6, 3.0)
    client.wait_goal(stamp, ('executing',), graph.check)
    graph['dual_stage'].signal_group(signal.SIGSTOP)
    stopped_at = time.monotonic()                  # the signal sent: its last timer call came before
    _, state, reason = client.wait_goal(stamp, TERMINAL, graph.check)
    assert state == 'aborted' and f'machine faulted: missing command for {fine} ' in reason, reason
    client.wait(lambda: client.diag('hw_sim', 'fault') != '', 'hw_sim naming the fault', GUARD, graph.check)
    assert client.diag('hw_sim', 'fault') in reason
    client.wait(lambda: 'dual_stage/offsets (none for step' in client.diag('servo_fine', 'waiting_for'),
                'servo_fine naming the offsets it lacks', GUARD, graph.check)
    stalled = time.monotonic() - stopped_at       # a lower bound of the gap it logs
    graph['dual_stage'].signal_group(signal.SIGCONT)
    client.wait(answering(client, 'servo_fine'), 'servo_fine answering the held step', GUARD, graph.check)
    client.wait(lambda: stall_logged(graph, 'dual_stage', stalled), f'dual_stage logging a stall of {stalled:.1f} s',
                GUARD, graph.check)
    faulted(client, graph)
    reset_and_move(client, graph, 'x_f')


# -- the trajectory node: clients learn it is lost; its goal never goes on --------------------

def test_a_killed_trajectory_makes_move_exit_with_the_reason_and_the_servos_hold(micromill, graph, client, ros_env):
    here = client.truth[0]
    slow_move_cli(client, graph, ros_env, 'move')
    kill(graph, 'trajectory')
    assert graph.wait('move', GUARD) == 1
    lines = graph['move'].tail(5)
    assert lines[-1].startswith('machine-ctrl: lost: the trajectory node (no sign of life'), lines
    # the servos run out of reference and hold its last row: hw_sim does not fault
    client.wait(lambda: int(client.diag('servo_coarse', 'reference_underruns', '0')) > 0, 'an underrun', GUARD,
                graph.check)
    assert client.diag('hw_sim', 'fault') == ''
    assert abs(client.truth[0] - here - 5e-3) > 1e-3            # stopped short of the goal
    restart(graph, micromill, 'trajectory')
    client.wait(lambda: client.trajectory_alive and client.status().get('state') == 'idle'
                and client.status().get('streamed_to_step') != '', 'the new trajectory node streaming', GUARD,
                graph.check)
    held = client.truth.copy()
    step = int(client.status()['streamed_to_step'])
    client.wait(lambda: int(client.diag('hw_sim', 'step') or 0) > step, 'its first rows played', GUARD, graph.check)
    assert abs(client.truth[0] - held[0]) < 5e-6                # it holds where the machine stands
    stamp, _ = slow_goal(client, distance=-1e-3, seconds=0.0)
    assert succeeded(client, stamp, graph)


def test_a_stopped_trajectory_aborts_its_goal_on_cont_and_the_motion_does_not_go_on(micromill, graph, client):
    here = client.truth[0]
    stamp, target = slow_goal(client, distance=5e-3, seconds=20.0)
    goal_id, _, _ = client.wait_goal(stamp, ('executing',), graph.check)
    graph['trajectory'].signal_group(signal.SIGSTOP)
    client.wait(lambda: client.trajectory_lost is not None, 'the trajectory node taken for lost', GUARD, graph.check)
    underruns = int(client.diag('servo_coarse', 'reference_underruns', '0'))
    client.wait(lambda: int(client.diag('servo_coarse', 'reference_underruns', '0')) > underruns,
                'the servos out of reference', GUARD, graph.check)
    held = client.truth.copy()                  # the servos hold their last row
    graph['trajectory'].signal_group(signal.SIGCONT)
    _, state, reason = client.wait_goal(stamp, TERMINAL, graph.check)
    assert state == 'aborted' and reason.startswith('trajectory stalled: its process did not run for'), reason
    client.wait(lambda: client.status().get('state') == 'idle', 'idle', GUARD, graph.check)
    end = int(client.status()['streamed_to_step'])
    client.wait(lambda: int(client.diag('hw_sim', 'step') or 0) > end, 'every streamed row played', GUARD,
                graph.check)
    assert abs(client.truth[0] - here) < abs(target - here) / 2            # far from the goal: it did not go on
    assert abs(client.truth[0] - held[0]) < 1e-6, client.truth[0] - held[0]   # where the servos held: no jump
    stamp, _ = slow_goal(client, distance=-0.5e-3, seconds=0.0)
    assert succeeded(client, stamp, graph)


# -- hw_sim: the trajectory node aborts the goal naming it; hw_sim faults itself on SIGCONT -------

def test_a_stopped_hw_sim_aborts_the_goal_naming_it_and_faults_itself_when_continued(micromill, graph, client):
    stamp, target = slow_goal(client, seconds=3.0)
    client.wait_goal(stamp, ('executing',), graph.check)
    graph['hw_sim'].signal_group(signal.SIGSTOP)
    stopped_at = time.monotonic()                  # the signal sent: hw_sim's last timer call came before
    _, state, reason = client.wait_goal(stamp, TERMINAL, graph.check)
    assert state == 'aborted' and reason.startswith('machine faulted: hw_sim lost: no sign of life'), reason
    faulted(client, graph)
    # hw_sim faults itself when a timer call comes more than command_timeout (5 s) after the one
    # before (hw_sim.session LockStepSession.watch, on every timer, before anything else can
    # fault it); the one before came before the SIGSTOP, so a stall longer than COMMAND_TIMEOUT
    # since `stopped_at` is a stall hw_sim sees. The abort does not tell that (the lease, 6 s,
    # may run out from a third of it on: contract.LIVELINESS_LEASE), so hw_sim stays stopped
    # until that lower bound holds (+1 s of margin) — a wait on a condition, not a measured time
    client.wait(lambda: time.monotonic() - stopped_at > COMMAND_TIMEOUT + 1.0, 'hw_sim stopped past command_timeout',
                GUARD, graph.check)
    stalled = time.monotonic() - stopped_at
    graph['hw_sim'].signal_group(signal.SIGCONT)
    client.wait(lambda: client.diag('hw_sim', 'fault').startswith('hw_sim stalled: its process did not run for'),
                'hw_sim faulting itself as stalled', GUARD, graph.check)
    fault = client.diag('hw_sim', 'fault')
    assert fault.endswith(f'(stopped or starved; limit command_timeout {COMMAND_TIMEOUT:g} s)'), fault
    # its gap is at least the stall made here (printed to 0.1 s: 6.04 s reads '6.0')
    assert float(fault.split(' for ')[1].split(' s')[0]) >= stalled - 0.1, (fault, stalled)
    faulted(client, graph)                         # the trajectory node keeps the fault hw_sim reports
    reset_and_move(client, graph, still=False)
    assert abs(client.truth[0] - target) > 0.5e-3 - 1e-4     # the aborted goal did not go on (+0.5 mm since)


def test_a_killed_hw_sim_aborts_the_goal_and_move_exits_with_the_reason(micromill, graph, client, ros_env):
    slow_move_cli(client, graph, ros_env, 'move_2')
    kill(graph, 'hw_sim')
    assert graph.wait('move_2', GUARD) == 1
    lines = graph['move_2'].tail(5)
    assert lines[-1].startswith('machine-ctrl: aborted: machine faulted: hw_sim lost: no sign of life'), lines
    faulted(client, graph)
    graph.check()                                  # every other node still up
