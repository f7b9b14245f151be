"""The tracking system of a Cartesian coupling (issue [4/8]: "robot path deviation measured by a
tracking system (§2.4) and cancelled by the piezo stage"): what hw_sim's tracker reads, the
message that carries it and its refusals, its config, and a hypothesis fuzz of dual_stage's
tracker input: a real DualStageNode in this process, its subscription's callback handed each
message (no graph: the graph run, with three bad readings over DDS, is
test_robot_piezo_graph.py's; the fuzz campaign's graph runs the micromill, which has no
tracker)."""
import dataclasses
import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hw_sim.simulator import MachineSimulator
from machine_ctrl.model.config import load_machine
from machine_ctrl.model.errors import ConfigError
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.model.numeric import MAX_COORDINATE
from machine_ctrl.ros import messages as ros_io
import fuzz_cases as fc
from test_config import edited_machine
from test_tool_deflection import in_the_block

RESOLUTION = 0.2e-6       # the config's Keyence LK-G87, Sörnmo section 2.5


def quantized(values):
    return tuple(RESOLUTION * math.floor(v / RESOLUTION + 0.5) for v in values)


def test_the_tracker_reads_the_robots_tool_tip_with_the_stage_at_home_and_the_deflection(robot_piezo):
    kin = Kinematics.from_config(robot_piezo)
    assert robot_piezo.tracker.resolution == RESOLUTION
    start = in_the_block(robot_piezo)
    sim = MachineSimulator(robot_piezo, initial_position=start)
    assert sim.measurement.tracker == quantized(kin.forward(np.array(start))[0])
    command = list(start)
    command[6] = 50e-6                                    # px: the stage moves the tool, the robot does not
    for k in range(1, 400):
        command[0] = start[0] + 1e-3 * k * 1e-4           # j1 turning: the tool tip feeds along the face
        sim.step(command)
    assert sim.deflection != 0.0 and abs(sim.true_position[6]) > 1e-6
    robot = list(sim.true_position)
    robot[6:] = start[6:]
    tip = kin.forward(np.array(robot))[0] + [0.0, 0.0, sim.deflection]
    assert sim.measurement.tracker == quantized(tip)


def test_tracker_noise_is_seeded_from_the_config(robot_piezo):
    noisy = dataclasses.replace(robot_piezo, cartesian_dual_stage=dataclasses.replace(
        robot_piezo.cartesian_dual_stage, tracker=dataclasses.replace(robot_piezo.tracker, noise=1e-6, resolution=0.0)))
    other_seed = dataclasses.replace(noisy, simulation=dataclasses.replace(noisy.simulation, seed=2))

    def readings(machine):
        sim = MachineSimulator(machine)
        return np.array([sim.step(machine.home).tracker for _ in range(2000)])
    first = readings(noisy)
    assert np.array_equal(first, readings(noisy))
    assert not np.array_equal(first, readings(other_seed))
    assert np.std(first, axis=0) == pytest.approx([1e-6] * 3, rel=0.1)        # 2000 readings: +-3 %


def test_a_tracker_message_carries_the_reading_and_a_bad_one_is_refused_with_the_reason():
    stamp = Time(sec=1, nanosec=500)
    msg = ros_io.tracker_message(stamp, 'workpiece', (0.1, -2e-6, -2.0))
    assert ros_io.tracker_reading(msg, 'workpiece') == (0.1, -2e-6, -2.0)
    with pytest.raises(ros_io.InvalidMessage, match=r"tracker frame_id 'workpiece' is not the workpiece frame 'wp'"):
        ros_io.tracker_reading(msg, 'wp')
    msg.point.z = -2.000001
    with pytest.raises(ros_io.InvalidMessage, match=r'tracker point \[0.1, -2e-06, -2.000001\] m is beyond \+-2 m of the '
                                                    r'workpiece origin'):
        ros_io.tracker_reading(msg, 'workpiece')
    msg.point.y = math.nan
    with pytest.raises(ros_io.InvalidMessage, match='point holds NaN or inf'):
        ros_io.tracker_reading(msg, 'workpiece')


def test_a_bad_tracker_config_is_refused_with_the_reason(tmp_path):
    edit = ('    resolution: 2.0e-7 ', '    resolution: -2.0e-7 ')
    with pytest.raises(ConfigError, match=r'cartesian_dual_stage\.tracker\.resolution: must be >= 0'):
        load_machine(edited_machine(tmp_path, edit, name='robot_piezo'))
    edit = ('    noise: 0.0 ', '    noise: 0.0\n    rate: 1000 ')
    with pytest.raises(ConfigError, match=r'cartesian_dual_stage\.tracker: .*rate'):
        load_machine(edited_machine(tmp_path, edit, name='robot_piezo'))


# on the control grid (robot_piezo steps at 10 kHz like the micromill, whose grid fuzz_cases
# draws on): a few steps ahead (kept for their step), or the campaign's bad stamps
_STAMPS = st.one_of(st.integers(0, 50).map(fc.on_grid), fc.any_stamp)
_COORDINATE = st.one_of(fc.any_float, st.floats(-2.5, 2.5))


@settings(max_examples=400, derandomize=True, deadline=None, database=None,
          suppress_health_check=(HealthCheck.function_scoped_fixture,))
@given(frame=st.one_of(st.just('workpiece'), fc.frame), stamp=_STAMPS, point=st.tuples(*[_COORDINATE] * 3))
def test_fuzzed_tracker_messages_are_refused_with_the_reason_or_kept_for_their_step(dual_stage_node, frame, stamp,
                                                                                    point):
    """A reading in the workpiece frame, on the control grid, finite and within 2 m of the
    origin is kept for its step (a well-formed reading is trusted, whoever sends it: README
    "Bringup and the command API"); anything else is refused, counted, with the reason, and
    nothing is kept. The callback never raises."""
    node = dual_stage_node
    before = dict(node.tracker.pending), node.rejections.count
    node.on_tracker(ros_io.tracker_message(Time(sec=stamp[0], nanosec=stamp[1]), frame, point))
    step = fc.stamp_step(stamp)
    valid = frame == 'workpiece' and step is not None and all(math.isfinite(v) and abs(v) <= 2.0 for v in point)
    assert MAX_COORDINATE == 2.0
    if valid:
        assert node.rejections.count == before[1] and node.tracker.pending[step] == point
    else:
        assert node.rejections.count == before[1] + 1 and node.tracker.pending == before[0]
        assert node.rejections.last.startswith('tracker: ') and len(node.rejections.last) > len('tracker: ')


@pytest.fixture
def dual_stage_node(rclpy_context, robot_piezo):
    from rclpy.parameter import Parameter

    from machine_ctrl.ros.dual_stage_node import DualStageNode
    node = DualStageNode(context=rclpy_context,
                         parameter_overrides=[Parameter('machine', value=str(robot_piezo.yaml_path))])
    try:
        assert node.coupling.uses_tracker and node.clock.period_ns == fc.PERIOD_NS     # the stamps' grid
        yield node
    finally:
        node.destroy_node()
