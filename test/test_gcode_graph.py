"""A G-code program on the running graph as a user runs it (issue [7/8], part 1): `machine-ctrl
bringup trt_5axis --record DIR`, `machine-ctrl send circle.ngc`, the trajectory node's feed
read back, Ctrl-C; the recorded joint states put the tool tip (forward kinematics) where the
program ends. Real nodes over real DDS; the pieces' geometry is test_gcode.py's."""
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np

from machine_ctrl.app.bringup import client_session
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.recording.bag import Bag
from test_gcode import CIRCLE

EXE = str(Path(sys.executable).with_name('machine-ctrl'))


def test_send_runs_a_program_piece_by_piece_and_leaves_the_feed_as_it_was(ros_supervisor, ros_env, tmp_path, trt):
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    program = tmp_path / 'circle.ngc'
    program.write_text(CIRCLE)
    bag = tmp_path / 'bag'
    child = ros_supervisor.start('bringup', [EXE, 'bringup', 'trt_5axis', '--record', str(bag)])
    ros_supervisor.wait_for_line('bringup', 'all nodes ready', timeout=180)
    sent = subprocess.run([EXE, 'send', str(program), '--machine', 'trt_5axis', '--timeout', '600'], env=ros_env,
                          capture_output=True, text=True, timeout=700, stdin=subprocess.DEVNULL)
    assert sent.returncode == 0, sent.stdout + sent.stderr
    lines = sent.stdout.splitlines()
    assert [line for line in lines if line.startswith('piece ')] == [
        'piece 1 of 5: lines 3-3, rapid', 'piece 2 of 5: lines 4-4, feed 5 mm/s', 'piece 3 of 5: lines 5-5, feed 10 mm/s',
        'piece 4 of 5: lines 6-6, feed 10 mm/s', 'piece 5 of 5: lines 7-7, rapid']
    assert sum(line.startswith('done: ') for line in lines) == 5
    with client_session(trt, 'gcode_test') as client:
        assert client.get_parameters('trajectory', ['feed']) == {'feed': 0.01}      # the node's own, back
    child.signal_group(signal.SIGINT)
    assert ros_supervisor.wait('bringup', timeout=120) == 0
    with Bag(bag) as recorded:
        *_, last = recorded.messages(['/joint_states'])
    state = deserialize_message(last.data, JointState)
    tip, _ = Kinematics.from_config(trt).forward(np.array(state.position))
    # the program's end (the block before it ended 0.5 mm lower), within the servos' error at rest
    # as the sensors read it (2.4 µm in x measured)
    assert np.abs(tip - np.array([1e-3, 0.0, 0.5e-3])).max() < 10e-6
