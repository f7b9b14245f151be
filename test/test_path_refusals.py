"""A nav_msgs/Path as the trajectory node receives it (machine_ctrl.ros.messages.path_to_cl):
every refusal names the pose and what is wrong with it."""
import math

import numpy as np
import pytest
from nav_msgs.msg import Path

from machine_ctrl.ros import messages as ros_io
from trajectory import toolpath


def path(quaternions, positions=None):
    msg = Path()
    msg.header.frame_id = 'workpiece'
    if positions is None:
        positions = [(i * 1e-3, 0.0, 0.0) for i in range(len(quaternions))]
    for p, q in zip(positions, quaternions):
        pose = ros_io.PoseStamped()
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = p
        pose.pose.orientation.x, pose.pose.orientation.y, pose.pose.orientation.z, pose.pose.orientation.w = q
        msg.poses.append(pose)
    return msg


UNIT = (0.0, 0.0, 0.0, 1.0)


@pytest.mark.parametrize('bad, message', [
    ((0.0, 0.0, 0.0, 0.5), r'pose 3: orientation quaternion has norm 0.5, not unit '
                           r'\(\|x² \+ y² \+ z² \+ w² - 1\| must be below 0.01\)'),
    ((0.0, 0.0, 0.0, 0.0), 'pose 3: orientation quaternion has zero length, not unit'),
    ((0.0, 0.0, math.nan, 1.0), r'pose 3: orientation quaternion is not finite \(NaN or inf\)'),
])
def test_a_bad_orientation_is_refused_naming_the_pose(bad, message):
    with pytest.raises(ValueError, match=message):
        ros_io.path_to_cl(path([UNIT] * 3 + [bad] + [UNIT] * 4), 'workpiece')


def test_a_nearly_unit_orientation_is_accepted_as_tf2_accepts_it():
    # |0.996² - 1| = 0.008 < 0.01: the rotation of the normalized quaternion (+z: 90 deg about z)
    h = 0.996 * math.sqrt(0.5)
    cl = ros_io.path_to_cl(path([UNIT] * 3 + [(0.0, 0.0, h, h)] + [UNIT] * 4), 'workpiece')
    np.testing.assert_allclose(cl.axes[3], [0.0, 0.0, 1.0], atol=1e-15)


def test_too_few_poses_are_refused_with_the_fewest_the_spline_needs():
    with pytest.raises(ValueError, match='5 points, need at least 6'):
        ros_io.path_to_cl(path([UNIT] * 5), 'workpiece')
    assert len(ros_io.path_to_cl(path([UNIT] * 6), 'workpiece')) == toolpath.MIN_POINTS == 6


def test_a_repeated_position_names_both_points_and_the_spacing():
    positions = [(i * 1e-3, 0.0, 0.0) for i in range(8)]
    positions[5] = (4e-3 + 1e-12, 0.0, 0.0)
    with pytest.raises(ValueError, match=r'point 5 repeats point 4: points 4 and 5 are 1e-12 m apart '
                                         r'\(need >= 1e-09 m\)'):
        ros_io.path_to_cl(path([UNIT] * 8, positions), 'workpiece')
