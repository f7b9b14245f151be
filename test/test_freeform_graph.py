"""A freeform cut through the running graph (issue [3/8] "Done when"): `machine-ctrl bringup
fts_lathe --single-process --record` at the PID's 199.6 kHz (one process: README "Quick
start"), `machine-ctrl freeform` (the trajectory node's freeform.* parameters and
/trajectory/freeform) as another program would, Ctrl-C, then the bag: the reference the
servos got is the cut trajectory/freeform.py computes, row for row, W followed it, W's
accelerometer was recorded for every state, and `machine-ctrl analyze` reads the session."""
import json
import math
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np

from machine_ctrl.recording import analysis
from trajectory.freeform import SinusoidalGrid, Turning, freeform_program
from trajectory.moves import AxisState

EXE = str(Path(sys.executable).with_name('machine-ctrl'))
CUT = Turning(2 * math.pi / 60, 5e-6, 0.05e-3, 0.002)    # 1 rpm, r = 0.05 mm, 2 ms: a short graph run
LEAD = 0.002                                                # s: W lands in 2 ms


def test_a_freeform_cut_runs_through_the_fts_lathe_graph_recorded_and_analysed(ros_supervisor, ros_env,
                                                                                  tmp_path, fts_lathe):
    bag = tmp_path / 'bag'
    child = ros_supervisor.start('bringup', [EXE, 'bringup', 'fts_lathe', '--single-process', '--record', str(bag)])
    ros_supervisor.wait_for_line('bringup', 'all nodes ready', timeout=180)

    def freeform(*args):
        return subprocess.run([EXE, 'freeform', *args, '--machine', 'fts_lathe'], env=ros_env,
                              capture_output=True, text=True, timeout=600)
    refused = freeform('spiral')
    assert refused.returncode == 1 and "refused: freeform: planning failed: surface 'spiral'" in refused.stderr, \
        refused.stderr
    done = freeform('sinusoidal_grid', '--rpm', '1', '--feed-per-rev', '5e-6', '--radius', '0.00005',
                    '--duration', '0.002', '--angle', '0', '--lead', '0.002')
    assert done.returncode == 0, done.stderr
    assert 'done: freeform sinusoidal_grid' in done.stdout
    child.signal_group(signal.SIGINT)
    assert ros_supervisor.wait('bringup', timeout=120) == 0

    run = analysis.load(bag)
    program = freeform_program(fts_lathe, SinusoidalGrid(), CUT, AxisState.at_rest(fts_lathe.home), lead=LEAD)
    expected = program.reference.position           # planned apart here: the node planned it in its process
    start = int(np.flatnonzero(np.abs(run.reference - expected[1]).max(axis=1) == 0)[0]) - 1
    np.testing.assert_array_equal(run.reference[start:start + len(expected)], expected)     # row for row
    first, end = program.cut
    w = fts_lathe.axis_names.index('w')
    following = run.reference[start + first:start + end, w] - run.measured[start + first:start + end, w]
    assert run.reference[start + first:start + end, w].min() > 1e-6          # W landed on the surface (1.5 um)
    assert np.abs(following).max() < 100e-9         # W followed: tens of nm after a 2 ms landing on ~1.5 um
    # W's accelerometer is in the bag (sensor_msgs/Imu on /accelerometers), one reading for
    # every recorded state's step, along W's joint axis (z of the link fts)
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Imu

    from machine_ctrl.recording.bag import Bag
    from machine_ctrl.recording.cdr import stamp_ns
    with Bag(bag) as reader:
        states = {stamp_ns(m.data) for m in reader.messages(['/joint_states'])}
        readings = [deserialize_message(m.data, Imu) for m in reader.messages(['/accelerometers'])]
    stamps = {r.header.stamp.sec * 10**9 + r.header.stamp.nanosec for r in readings}
    assert states and states <= stamps
    assert {r.header.frame_id for r in readings} == {'fts'}
    assert all(r.linear_acceleration.x == r.linear_acceleration.y == 0.0 for r in readings)
    assert np.ptp([r.linear_acceleration.z for r in readings]) > 0           # W's landing and noise
    analyzed = subprocess.run([EXE, 'analyze', str(bag), '--json'], env=ros_env, capture_output=True, text=True,
                              timeout=300)
    assert analyzed.returncode == 0, analyzed.stderr
    assert json.loads(analyzed.stdout)['runs'][0]['machine'] == 'fts_lathe'
