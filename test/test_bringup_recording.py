"""`machine-ctrl bringup --record` when the recording or the contour estimate is lost: the
machine does not vanish (a non-control node's loss does not stop it).

* End to end: the recorder process of a running bringup is killed (SIGKILL); bringup says
  so in one line naming `machine-ctrl record --recover`, and the same for contour_error,
  which it starts again (test_bringup_respawn.py: the rule); the graph keeps running (a
  `move` succeeds afterwards), Ctrl-C stops everything with exit status 1 (the recording was
  lost), and the recovered bag opens.
* Bringup's rule, with a stand-in recorder process (no ROS): before the graph is ready a
  recorder that ends stops the bringup (hw_sim waits at step 0 for it); after, it is one
  notice and the graph runs on, unless stop_on_recording_loss asks to stop everything.
"""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from machine_ctrl.app.bringup import Bringup, RecordingLost
from machine_ctrl.app.processes import ChildExited
from machine_ctrl.recording.bag import Bag
from ros_fixtures import on_disk

EXE = str(Path(sys.executable).with_name('machine-ctrl'))
STAND_IN = [sys.executable, '-c', 'import time; print("recording to it", flush=True); time.sleep(600)']


def node_pid(domain_id: str, module: bytes = b'machine_ctrl.ros.recorder_node') -> int:
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / 'cmdline').read_bytes().split(b'\0')
            environ = (entry / 'environ').read_bytes().split(b'\0')
        except OSError:
            continue
        if module in cmdline and f'ROS_DOMAIN_ID={domain_id}'.encode() in environ:
            return int(entry.name)
    raise AssertionError(f'no process of {module.decode()}')


def test_a_killed_recorder_or_contour_error_does_not_stop_the_machine(ros_supervisor, ros_env, tmp_path):
    bag = tmp_path / 'bag'
    child = ros_supervisor.start('bringup', [EXE, 'bringup', '--record', str(bag)])
    ros_supervisor.wait_for_line('bringup', 'all nodes ready', timeout=180)
    # states in a complete chunk on disk (a chunk completes within 1 s, README "Recording"):
    # what the kill must not lose
    deadline = time.monotonic() + 120
    while on_disk(bag / 'bag_0.mcap', '/joint_states') == 0:
        assert time.monotonic() < deadline, 'no /joint_states in a complete chunk'
        time.sleep(0.05)
    flushed = on_disk(bag / 'bag_0.mcap', '/joint_states')
    os.kill(node_pid(ros_env['ROS_DOMAIN_ID']), signal.SIGKILL)
    line = ros_supervisor.wait_for_line('bringup', 'recording stopped: ', timeout=30)
    assert line.startswith('recording stopped: recorder exited with code -9 (killed by SIGKILL) (its log: ')
    assert line.endswith(f'recorder.log); the bag may need machine-ctrl record --recover {bag}; '
                         f'the graph keeps running')
    os.kill(node_pid(ros_env['ROS_DOMAIN_ID'], b'machine_ctrl.ros.contour_error_node'), signal.SIGKILL)
    line = ros_supervisor.wait_for_line('bringup', 'contour_error exited with', timeout=30)
    assert line.startswith('contour_error exited with code -9 (killed by SIGKILL) (its log: ')
    assert 'starting it again in 8.5 s; the graph keeps running' in line
    started = time.monotonic()
    done = subprocess.run([EXE, 'move', 'x_c=0.001'], env=ros_env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr                   # the machine is still there
    # hw_sim holds for the dead recorder until its liveliness lease (5 s) runs out
    print(f'move after the kill took {time.monotonic() - started:.1f} s')
    ros_supervisor.wait_for_line('bringup', 'contour_error started again (1 of 3)', timeout=120)
    child.signal_group(signal.SIGINT)
    assert ros_supervisor.wait('bringup', timeout=120) == 1
    output = '\n'.join(child.tail(200))
    assert 'machine-ctrl: bringup:' not in output              # nothing failed but the recording
    recovered = subprocess.run([EXE, 'record', '--recover', str(bag)], env=ros_env, capture_output=True,
                               text=True, timeout=300)
    assert recovered.returncode == 0, recovered.stderr
    with Bag(bag) as readable:
        assert sum(1 for _ in readable.messages(['/joint_states'])) >= flushed > 0


@pytest.fixture
def stand_in(tmp_path, micromill):
    """A Bringup whose recorder is a stand-in process (its graph: none)."""
    made = []

    def make(**options):
        bringup = Bringup(micromill, record=str(tmp_path / 'bag'), log_dir=str(tmp_path / 'logs'), **options)
        bringup.recorder.start('recorder', STAND_IN)
        bringup.recorder.wait_for_line('recorder', 'recording to', timeout=30)
        made.append(bringup)
        return bringup
    yield make
    for bringup in made:
        bringup.stop()


def _kill(bringup):
    child = bringup.recorder['recorder']
    child.signal_group(signal.SIGKILL)
    child.process.wait(30)


def test_a_recorder_that_ends_before_the_graph_is_ready_stops_the_bringup(stand_in):
    bringup = stand_in()
    _kill(bringup)
    with pytest.raises(ChildExited, match='killed by SIGKILL'):
        bringup.check()


def test_a_recorder_that_ends_later_is_one_notice_and_the_graph_runs_on(stand_in, tmp_path):
    bringup = stand_in()
    bringup.ready = True
    bringup.check()
    assert bringup.notices == [] and bringup.recording_lost is None
    _kill(bringup)
    bringup.check()
    bringup.check()
    text = (f'recording stopped: recorder exited with code -9 (killed by SIGKILL) (its log: {tmp_path}/logs/'
            f'recorder.log); the bag may need machine-ctrl record --recover {tmp_path / "bag"}')
    assert bringup.notices == [f'{text}; the graph keeps running']
    assert bringup.stop() == [text]


def test_stop_on_recording_loss_stops_everything_with_the_reason(stand_in):
    bringup = stand_in(stop_on_recording_loss=True)
    bringup.ready = True
    _kill(bringup)
    with pytest.raises(RecordingLost, match=r'recorder exited with code -9 .*--stop-on-recording-loss'):
        bringup.check()
    diagnosed = stand_in(stop_on_recording_loss=True)
    with pytest.raises(RecordingLost, match='recording stopped: disk full'):
        diagnosed.lose_recording('disk full (the recorder is still up)')     # what /diagnostics says


def test_the_recorders_error_on_diagnostics_is_heard_once(ros_node):
    """The shell's RecorderStatus: a recorder that stays up reports its stopped recording on
    /diagnostics (every second); other entries are not its business. On a real node: its
    subscription is the one it makes (topic, type), its callback fed here directly."""
    from types import SimpleNamespace

    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    from machine_ctrl.app.bringup import RecorderStatus
    node = ros_node('recorder_status_test')
    status = RecorderStatus(SimpleNamespace(node=node))
    (subscription,) = node.subscriptions
    assert (subscription.topic_name, subscription.msg_type) == ('/diagnostics', DiagnosticArray)
    hear = subscription.callback
    hear(DiagnosticArray(status=[DiagnosticStatus(name='hw_sim', level=DiagnosticStatus.ERROR, message='FAULT: x')]))
    assert status.stopped is None
    for reason in ('writing failed: No space left on device (ENOSPC)', 'later'):
        hear(DiagnosticArray(status=[DiagnosticStatus(name='recorder', level=DiagnosticStatus.ERROR,
                                                      message=f'recording stopped: {reason}')]))
    assert status.stopped == 'writing failed: No space left on device (ENOSPC) (the recorder is still up)'
