"""A G-code program on the running graph as a user runs it (issue [7/8], part 1): `machine-ctrl
bringup trt_5axis --single-process --record DIR` (one process: README "Quick start"),
`machine-ctrl send circle.ngc`, the trajectory node's feed read back, Ctrl-C; the recorded
joint states put the tool tip (forward kinematics) where the program ends; then the same
program's text on /trajectory/program, as another robot sends it: refused ones name the topic
and the line, the good one runs whole at its own feeds. Real nodes over real DDS; the pieces'
geometry is test_gcode.py's."""
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from machine_ctrl import contract
from machine_ctrl.app.bringup import client_session
from machine_ctrl.app.client import Timeout
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.recording.bag import Bag
from test_gcode import CIRCLE

EXE = str(Path(sys.executable).with_name('machine-ctrl'))


def test_send_runs_a_program_piece_by_piece_and_leaves_the_feed_as_it_was(ros_supervisor, ros_env, tmp_path, trt):
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from machine_ctrl.ros import messages as ros_io

    program = tmp_path / 'circle.ngc'
    program.write_text(CIRCLE)
    bag = tmp_path / 'bag'
    child = ros_supervisor.start('bringup', [EXE, 'bringup', 'trt_5axis', '--single-process', '--record', str(bag)])
    ros_supervisor.wait_for_line('bringup', 'all nodes ready', timeout=180)
    sent = subprocess.run([EXE, 'send', str(program), '--machine', 'trt_5axis', '--timeout', '600'], env=ros_env,
                          capture_output=True, text=True, timeout=700, stdin=subprocess.DEVNULL)
    assert sent.returncode == 0, sent.stdout + sent.stderr
    lines = sent.stdout.splitlines()
    assert [line for line in lines if line.startswith('piece ')] == [
        'piece 1 of 5: line 3, rapid', 'piece 2 of 5: line 4, feed 2 mm/s', 'piece 3 of 5: line 5, feed 5 mm/s',
        'piece 4 of 5: line 6, feed 5 mm/s', 'piece 5 of 5: line 7, rapid']
    assert sum(line.startswith('done: ') for line in lines) == 5
    with client_session(trt, 'gcode_test') as client:
        assert client.get_parameters('trajectory', ['feed']) == {'feed': 0.01}      # the node's own, back
        publisher = client.node.create_publisher(String, contract.PROGRAM.name, ros_io.qos(contract.PROGRAM.qos))
        topic = '/' + contract.PROGRAM.name
        client.wait(lambda: client.listens(publisher), 'the trajectory node reading the program topic')
        # a goal's /diagnostics entry is published once per change, on a volatile topic: the
        # client must hear the trajectory node there (its 1 Hz status) before the first program,
        # or on a loaded machine the first entry can go out before the two are matched
        client.wait(lambda: 'trajectory' in client.diagnostics_heard, "the trajectory node's /diagnostics")

        def run(text: str) -> tuple[str, str]:
            """Publish a program; (its goal's end state, the reason in its /diagnostics entry)."""
            known = set(client.goal_states)
            publisher.publish(String(data=text))
            ended = {}

            def finished() -> bool:
                new = [g for g in client.goal_states if g not in known]
                if new and client.goal_state(new[0]) in ('succeeded', 'aborted', 'canceled') \
                        and client.goal_entries.get(new[0], {}).get('status') == client.goal_state(new[0]):
                    ended.update(client.goal_entries[new[0]])
                    return True
                return False
            try:
                client.wait(finished, 'the program goal ending', timeout=600)
            except Timeout as exc:          # what the client had heard (run100 timed out with no word)
                new = {g: (client.goal_states[g], client.goal_entries.get(g)) for g in client.goal_states
                       if g not in known}
                pytest.fail(f'{exc}; new goals (states, /diagnostics entry): {new}; /diagnostics heard from: '
                            f'{sorted(client.diagnostics_heard)}')
            return ended['status'], ended['reason']

        assert run(CIRCLE.replace('G1 X1', 'G1 X1 Q3')) == (
            'aborted', f'program: planning failed: {topic}:6: Q3: the word Q is not supported')
        assert run(CIRCLE.replace('G1 X1', 'G1 X1\nM0')) == (
            'aborted', f'program: planning failed: {topic}:6: an M0 program stop follows this block, and a '
                       f'program sent on {topic} runs unattended (machine-ctrl send waits for Enter at an M0)')
        assert run(CIRCLE) == ('succeeded', '')
    child.signal_group(signal.SIGINT)
    assert ros_supervisor.wait('bringup', timeout=120) == 0
    with Bag(bag) as recorded:
        states = [deserialize_message(m.data, JointState) for m in recorded.messages(['/joint_states'])]
    kinematics = Kinematics.from_config(trt)
    # both runs of the circle (sent, then on the topic) at the program's 5 mm/s, not the node's
    # own 10 mm/s: the time (sim, every 10th state) the tool tip spent on its 324 degrees away
    # from the start, 2.26 s at 5 mm/s (1.13 s at 10); the runs are seconds apart
    on_circle = np.array([s.header.stamp.sec + 1e-9 * s.header.stamp.nanosec for s in states[::10]
                          if _on_circle(kinematics.forward(np.array(s.position))[0])])
    runs = np.split(on_circle, np.flatnonzero(np.diff(on_circle) > 1.0) + 1)
    assert len(runs) == 2 and all(1.9 < run[-1] - run[0] < 2.6 for run in runs), [(r[0], r[-1]) for r in runs]
    tip, _ = kinematics.forward(np.array(states[-1].position))
    # the program's end (the block before it ended 0.5 mm lower), within the servos' error at rest
    # as the sensors read it (2.4 µm in x measured)
    assert np.abs(tip - np.array([1e-3, 0.0, 0.5e-3])).max() < 10e-6


def _on_circle(tip) -> bool:
    """On the programmed circle (radius 2 mm, z 0) and away from its start and end at (2, 0) mm."""
    return abs(np.hypot(tip[0], tip[1]) - 2e-3) < 10e-6 and abs(tip[2]) < 10e-6 and tip[0] < 1.9e-3
