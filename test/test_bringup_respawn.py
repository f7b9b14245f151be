"""`machine-ctrl bringup`'s rule for a node process that ends on its own (README "Faults"),
with stand-in processes for the nodes (no ROS): once the graph is ready, a node that dies is
one notice and starts again after the respawn delay (the launch file's), at most
RESPAWN_MAX times, the graph running on meanwhile; a node that exits 0 was asked to stop
from outside and is not started again; hw_sim's end stops the bringup, as does any end before
the graph is ready. The end-to-end case (a real contour_error killed under bringup) is in
test_bringup_recording.py."""
import signal
import sys
import time

import pytest

from machine_ctrl.app.bringup import RESPAWN_MAX, Bringup
from machine_ctrl.app.processes import ChildExited

# exits 0 on SIGTERM, as every node does when asked to stop
STAND_IN = [sys.executable, '-c', 'import signal, sys, time; signal.signal(signal.SIGTERM, lambda *_: sys.exit(0)); '
                                  'print("up", flush=True); time.sleep(600)']
NODES = ('hw_sim', 'servo_fine', 'contour_error')
DEADLINE = 60.0             # s: a hang fails the test after this long, nothing is timed


@pytest.fixture
def bringup(tmp_path, micromill):
    """A Bringup whose graph is stand-ins, ready, starting a dead node again after 0.2 s."""
    made = Bringup(micromill, log_dir=str(tmp_path / 'logs'))
    for name in NODES:
        made.graph.start(name, STAND_IN)
    for name in NODES:
        made.graph.wait_for_line(name, 'up', timeout=DEADLINE)
    made.ready = True
    made.respawn_delay = 0.2
    yield made
    made.stop()


def end(bringup, name, sig=signal.SIGKILL):
    child = bringup.graph[name]
    child.signal_group(sig)
    child.process.wait(DEADLINE)
    return child


def until_started_again(bringup, name, old):
    deadline = time.monotonic() + DEADLINE
    while bringup.graph[name] is old:
        assert time.monotonic() < deadline, f'{name} not started again'
        bringup.check()
        time.sleep(0.02)
    bringup.graph.wait_for_line(name, 'up', timeout=DEADLINE)


def test_the_delay_is_the_launch_files_detection_time_and_a_second():
    """hw_sim's command_timeout 5 s, the liveliness lease 6 s + its 1.5 s confirmation: the
    longer + 1 s (README "Faults")."""
    from machine_ctrl.model.config import load_machine
    assert Bringup(load_machine('micromill_9axis')).respawn_delay == 8.5


def test_a_dead_node_starts_again_each_time_up_to_the_limit_and_the_graph_runs_on(bringup, tmp_path):
    logs = tmp_path / 'logs'
    for n in range(1, RESPAWN_MAX + 1):
        old = end(bringup, 'servo_fine')
        bringup.check()
        assert bringup.notices[-1] == (f'servo_fine exited with code -9 (killed by SIGKILL) (its log: {logs}/'
                                       f'servo_fine.log); starting it again in 0.2 s; the graph keeps running '
                                       f'(a faulted machine continues with hw_sim/reset once it answers)')
        until_started_again(bringup, 'servo_fine', old)
        assert bringup.notices[-1] == f'servo_fine started again ({n} of {RESPAWN_MAX})'
        assert (logs / f'servo_fine.{n}.log').read_text() == 'up\n'        # each earlier log kept
    end(bringup, 'servo_fine')
    bringup.check()
    assert bringup.notices[-1].endswith(f': not started again (started again {RESPAWN_MAX} times already); '
                                        'the graph keeps running')
    count = len(bringup.notices)
    bringup.check()
    assert not bringup.graph['servo_fine'].running() and len(bringup.notices) == count
    assert bringup.graph.alive() == ['hw_sim', 'contour_error']


def test_a_node_asked_to_stop_from_outside_is_not_started_again(bringup, tmp_path):
    end(bringup, 'contour_error', signal.SIGTERM)
    bringup.check()
    assert bringup.notices == [f'contour_error exited with code 0 (its log: {tmp_path}/logs/contour_error.log): '
                               'asked to stop from outside, not started again; the graph keeps running']
    assert bringup.respawn_due == {}


def test_hw_sims_end_stops_the_bringup(bringup):
    end(bringup, 'hw_sim')
    with pytest.raises(ChildExited, match=r"child 'hw_sim' exited with code -9 \(killed by SIGKILL\)"):
        bringup.check()


def test_before_the_graph_is_ready_any_end_stops_the_bringup(bringup):
    bringup.ready = False
    end(bringup, 'contour_error')
    with pytest.raises(ChildExited, match=r"child 'contour_error' exited with code -9"):
        bringup.check()
