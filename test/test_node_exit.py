"""machine_ctrl.ros.node_common: a node process ends on SIGINT with exit 0 without deleting its
DDS participant (keep_participant, end_process: Fast DDS 2.14.5's participant deletion can
spin for ever), its entities still destroyed and announced, its output flushed, its
shared-memory segment removed. A real node process (ros_env: own domain)."""
import signal
import sys
from pathlib import Path

import pytest

from machine_ctrl.app.processes import Supervisor
from ros_fixtures import wait_until

# A node process (node_common's init and spin) with a publisher; it names the lock file of
# its participant's shared-memory segment (the one it holds open) and says 'ready'.
NODE = '''
import rclpy
from std_msgs.msg import String
from machine_ctrl import shared_memory
from machine_ctrl.ros import node_common
node_common.init([])
node = rclpy.create_node("ends_on_sigint")
pub = node.create_publisher(String, "/ends_on_sigint", 10)
locks = shared_memory.own_segment_locks()
print("segment lock", *locks, flush=True)
print("ready", flush=True)
node_common.spin([node])
'''


@pytest.fixture
def sup(ros_env, tmp_path):
    with Supervisor(log_dir=tmp_path / 'logs', stop_timeout=30.0) as supervisor:
        yield supervisor


def test_a_node_process_ends_on_sigint_with_exit_0_its_endpoints_gone_its_segment_cleaned(sup, ros_node):
    listener = ros_node('exit_listener')
    sup.start('node', [sys.executable, '-c', NODE])
    locks = sup.wait_for_line('node', 'segment lock', timeout=120).split()[2:]
    assert len(locks) == 1, locks                 # one participant, one segment
    lock = Path(locks[0])
    sup.wait_for_line('node', 'ready', timeout=120)
    wait_until(lambda: listener.count_publishers('/ends_on_sigint') == 1, 'the publisher discovered')
    sup['node'].process.send_signal(signal.SIGINT)
    assert sup['node'].process.wait(timeout=120) == 0
    log = (sup.log_dir / 'node.log').read_text()
    assert 'SIGINT: shutting down' in log and 'Traceback' not in log, log
    # the publisher's end announced (not left to the participant's 20 s lease, which cannot be
    # told apart here: only that it goes)
    wait_until(lambda: listener.count_publishers('/ends_on_sigint') == 0, 'the publisher gone')
    wait_until(lambda: ('ends_on_sigint', '/') not in listener.get_node_names_and_namespaces(), 'the node gone')
    # its segment and lock file removed by the process itself, as deleting its participant would
    assert not lock.exists() and not lock.with_name(lock.name[:-len('_el')]).exists()
