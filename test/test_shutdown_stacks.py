"""machine_ctrl.ros.node_common: a node whose shutdown hangs inside a call (as rclpy's destroy of a
service did in Fast DDS, run89 / run107) prints its native stacks, so the log says where below
Python it waits; a prompt shutdown prints nothing. Real node processes (ros_env: own domain)."""
import os
import re
import shutil
import signal
import sys

import pytest

from machine_ctrl.app.processes import Supervisor

PY_SPY = shutil.which('py-spy', path=os.pathsep.join((os.path.dirname(sys.executable), os.environ.get('PATH', ''))))
pytestmark = pytest.mark.skipif(PY_SPY is None, reason='py-spy is not installed (the test extras bring it)')

# A node process (node_common's init and spin) whose destroy_node hangs in a C call; its stacks
# are asked for 0.5 s into the shutdown and the process is ended only after 600 s (by the test).
HANGS_IN_DESTROY = '''
import threading
import rclpy
from machine_ctrl.ros import node_common
node_common.init([])
node_common.NATIVE_STACKS_AFTER = 0.5
node_common.SHUTDOWN_LIMIT = 600.0
node = rclpy.create_node("hangs_in_destroy")
def hung_in_destroy():
    threading.Event().wait()
node.destroy_node = hung_in_destroy
print("ready", flush=True)
node_common.spin([node])
'''
# The watcher alone: asked for stacks after 600 s, then the shutdown is done at once.
PROMPT = '''
from machine_ctrl.ros.node_common import native_stacks_later
watcher = native_stacks_later(600.0)
watcher.stdin.close()
print("watcher exited", watcher.wait(), flush=True)
'''


@pytest.fixture
def sup(ros_env, tmp_path):
    with Supervisor(log_dir=tmp_path / 'logs', stop_timeout=0.5) as supervisor:
        yield supervisor


def test_a_shutdown_hung_in_a_call_prints_its_native_and_python_stacks(sup):
    sup.start('hangs', [sys.executable, '-c', HANGS_IN_DESTROY])
    sup.wait_for_line('hangs', 'ready', timeout=120)
    sup['hangs'].process.send_signal(signal.SIGINT)
    # faulthandler stays silent for 600 s: only py-spy names the Python function here
    sup.wait_for_line('hangs', 'hung_in_destroy', timeout=120)
    sup.stop('hangs', timeout=0.5)
    log = (sup.log_dir / 'hangs.log').read_text()
    assert 'SIGINT: shutting down' in log, log
    assert re.search(r'Thread \d+ .*"MainThread"', log), log
    # native frames: a function in a shared library below the Python frames (libc's wait,
    # libpython's lock), which faulthandler cannot show
    assert re.search(r'^\s+\S+ \(\S*lib[^)]*\.so[^)]*\)$', log, re.MULTILINE), log


def test_a_prompt_shutdown_prints_nothing_and_its_watcher_exits_at_once(sup):
    sup.start('prompt', [sys.executable, '-c', PROMPT])
    # well before its 600 s
    assert sup.wait_for_line('prompt', 'watcher exited', timeout=120).split()[-1] == '0'
    assert sup['prompt'].process.wait(timeout=60) == 0
    assert 'Thread' not in (sup.log_dir / 'prompt.log').read_text()
