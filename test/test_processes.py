"""machine_ctrl.app.processes: the supervisor the graph tests and bringup rely on to start nodes
and, above all, to leave nothing running afterwards."""
import os
import signal
import sys
from pathlib import Path

import pytest

from machine_ctrl.app.processes import (ChildExited, Supervisor, exit_code_text, isolated_ros_env,
                                    reserve_ros_domain)

# Tiny children. Each prints 'ready' once its signal dispositions are in place, so a test
# never signals a child before it has had the chance to ignore the signal.
SLEEPER = 'import time; print("ready"); time.sleep(60)'
FAILS = 'import sys; print("starting"); print("config: bad key", file=sys.stderr); sys.exit(3)'
IGNORES_SIGINT = ('import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); '
                  'print("ready"); time.sleep(60)')
IGNORES_SIGINT_AND_SIGTERM = ('import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); '
                              'signal.signal(signal.SIGTERM, signal.SIG_IGN); print("ready"); time.sleep(60)')
# A node process (machine_ctrl.ros.node_common.init: its stop signals and its stacks report)
# whose main thread hangs in a call, so that no stop signal ends it (as a recorder once did).
HANGS_IN_A_CALL = ('import threading; from machine_ctrl.ros.node_common import init; init([]); '
                   'print("ready", flush=True)\n'
                   'def hung_in_a_call():\n    threading.Event().wait()\n'
                   'hung_in_a_call()')
# Starts a grandchild that survives SIGINT and SIGTERM, reports its pid, then behaves
# like a node (stays) or, with argv[1] == 'leave', exits and leaves the grandchild behind.
SPAWNER = f'''
import subprocess, sys, time
g = subprocess.Popen([sys.executable, "-c", {IGNORES_SIGINT_AND_SIGTERM!r}], stdout=subprocess.PIPE, text=True)
assert g.stdout.readline().strip() == "ready"
print("grandchild", g.pid, flush=True)
if sys.argv[1:] == ["leave"]:
    sys.exit(0)
time.sleep(60)
'''


def py(code, *args):
    return [sys.executable, '-c', code, *args]


def pid_alive(pid):
    """Running, i.e. present and not a zombie (orphans are never reaped in some containers)."""
    try:
        stat = Path(f'/proc/{pid}/stat').read_bytes()
    except FileNotFoundError:
        return False
    return stat[stat.rfind(b')') + 2:].split()[0] not in (b'Z', b'X')


@pytest.fixture
def sup(tmp_path):
    with Supervisor(log_dir=tmp_path / 'logs', stop_timeout=0.5) as supervisor:
        yield supervisor


def test_children_get_the_given_environment_and_their_own_process_group(tmp_path):
    env = isolated_ros_env(42, base={'PATH': os.environ.get('PATH', ''), 'ROS_LOCALHOST_ONLY': '1'})
    code = ('import os; print("env", os.environ["ROS_DOMAIN_ID"], os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"], '
            '"ROS_LOCALHOST_ONLY" in os.environ, os.getpgid(0) == os.getpid())')
    with Supervisor(env) as supervisor:
        supervisor.start('env', py(code))
        assert supervisor.wait_for_line('env', 'env', timeout=10) == 'env 42 LOCALHOST False True'
        assert supervisor.wait('env', timeout=10) == 0
        supervisor.check()      # a child that was waited for has not "exited early"


def test_an_exit_code_reads_as_the_signal_that_ended_the_process():
    assert exit_code_text(3) == 'code 3'
    assert exit_code_text(-signal.SIGKILL) == 'code -9 (killed by SIGKILL)'
    unnamed = signal.SIGRTMIN + 1                # real-time signals between MIN and MAX have no name
    assert exit_code_text(-unnamed) == f'code {-unnamed} (killed by signal {unnamed})'


def test_early_exit_is_reported_with_code_and_last_output(sup):
    sup.start('fails', py(FAILS))
    with pytest.raises(ChildExited) as exc_info:
        sup.wait_for_line('fails', 'ready', timeout=10)
    assert exc_info.value.returncode == 3
    assert exc_info.value.tail == ['starting', 'config: bad key']
    assert 'config: bad key' in str(exc_info.value)
    with pytest.raises(ChildExited, match="'fails' exited with code 3"):
        sup.check()
    assert sup.alive() == []


def test_sigint_is_enough_for_a_well_behaved_child(sup):
    sup.start('sleeper', py(SLEEPER))
    sup.wait_for_line('sleeper', 'ready', timeout=10)
    assert sup.alive() == ['sleeper']
    # killed by SIGINT itself, not by the SIGTERM that follows `timeout` s later (a generous
    # timeout: on a loaded machine a signalled child may take seconds to be scheduled)
    assert sup.stop('sleeper', timeout=30) == -signal.SIGINT
    sup.check()
    assert 'ready' in (sup.log_dir / 'sleeper.log').read_text()


def test_a_child_ignoring_sigint_gets_sigterm_then_sigkill(sup):
    sup.start('no_int', py(IGNORES_SIGINT))
    sup.start('no_int_no_term', py(IGNORES_SIGINT_AND_SIGTERM))
    for name in ('no_int', 'no_int_no_term'):
        sup.wait_for_line(name, 'ready', timeout=10)
    codes = sup.stop_all(timeout=3.0)     # per step; the child that ignores both takes 2 x 3 s
    assert codes == {'no_int_no_term': -signal.SIGKILL, 'no_int': -signal.SIGTERM}
    assert sup.alive() == []


def test_a_node_that_does_not_stop_leaves_its_stacks_in_its_log_before_sigkill(sup):
    """contract.STACKS_SIGNAL goes only to processes that catch it (the test above: the
    others are killed by SIGKILL, not by it)."""
    sup.start('hung', py(HANGS_IN_A_CALL))
    sup.wait_for_line('hung', 'ready', timeout=60)
    assert sup.stop('hung', timeout=1.0) == -signal.SIGKILL
    log = (sup.log_dir / 'hung.log').read_text()
    assert 'most recent call first' in log and 'in hung_in_a_call' in log, log


def test_stacks_returns_a_running_nodes_stacks_and_leaves_it_running(sup):
    """Supervisor.stacks, for a failure's report: the lines the node printed at
    contract.STACKS_SIGNAL, the node going on; none from a process that does not catch it."""
    sup.start('hung', py(HANGS_IN_A_CALL))
    sup.start('sleeper', py(SLEEPER))
    sup.wait_for_line('hung', 'ready', timeout=60)
    sup.wait_for_line('sleeper', 'ready', timeout=10)
    for _ in range(2):                   # the second report has only the second dump's lines
        lines = sup.stacks('hung')
        assert sum('most recent call first' in line for line in lines) >= 1, lines
        assert any('in hung_in_a_call' in line for line in lines) and 'ready' not in lines, lines
    assert sup['hung'].running()
    assert sup.stacks('sleeper') == [] and sup['sleeper'].running()


def test_stop_all_leaves_no_grandchild(sup):
    sup.start('spawner', py(SPAWNER))
    grandchild = int(sup.wait_for_line('spawner', 'grandchild', timeout=10).split()[1])
    assert pid_alive(grandchild)
    sup.stop_all(timeout=0.3)
    assert not pid_alive(grandchild)


def test_a_grandchild_left_behind_by_an_exited_child_is_stopped_too(sup):
    sup.start('leaver', py(SPAWNER, 'leave'))
    grandchild = int(sup.wait_for_line('leaver', 'grandchild', timeout=10).split()[1])
    sup['leaver'].process.wait(timeout=10)
    with pytest.raises(ChildExited):
        sup.check()
    assert pid_alive(grandchild)
    assert sup.stop_all(timeout=0.3) == {'leaver': 0}
    assert not pid_alive(grandchild)


def test_leaving_the_block_on_an_exception_stops_everything():
    with pytest.raises(KeyError):
        with Supervisor(stop_timeout=0.3) as supervisor:
            child = supervisor.start('no_int', py(IGNORES_SIGINT))
            supervisor.wait_for_line('no_int', 'ready', timeout=10)
            raise KeyError('test failure inside the block')
    assert child.returncode == -signal.SIGTERM
    assert not pid_alive(child.pid)


def test_wait_for_line_times_out_with_the_output_so_far(sup):
    sup.start('sleeper', py(SLEEPER))
    with pytest.raises(TimeoutError, match='ready'):
        sup.wait_for_line('sleeper', 'never printed', timeout=0.5)


def test_a_name_is_reusable_only_after_its_child_was_stopped(sup):
    sup.start('node', py(SLEEPER))
    with pytest.raises(ValueError):
        sup.start('node', py(SLEEPER))
    sup.stop('node')
    sup.start('node', py(SLEEPER))
    assert sup.alive() == ['node']


def test_domain_leases_are_exclusive_until_released(tmp_path):
    with reserve_ros_domain(5, 6, lock_dir=tmp_path) as a, reserve_ros_domain(5, 6, lock_dir=tmp_path) as b:
        assert {a.domain_id, b.domain_id} == {5, 6}
        with pytest.raises(RuntimeError, match='5..6'):
            reserve_ros_domain(5, 6, lock_dir=tmp_path)
        a.release()
        with reserve_ros_domain(5, 6, lock_dir=tmp_path) as c:
            assert c.domain_id == a.domain_id


def test_a_domain_held_by_another_process_is_skipped(tmp_path):
    hold = ('import fcntl, os, sys, time; fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT); '
            'fcntl.flock(fd, fcntl.LOCK_EX); print("ready"); time.sleep(60)')
    with Supervisor(stop_timeout=0.5) as supervisor:
        supervisor.start('holder', py(hold, str(tmp_path / 'ros_domain_id.7.lock')))
        supervisor.wait_for_line('holder', 'ready', timeout=10)
        with reserve_ros_domain(7, 8, lock_dir=tmp_path) as lease:
            assert lease.domain_id == 8
