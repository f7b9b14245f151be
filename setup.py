"""ament_python package machine_ctrl.

Besides the Python packages this installs, under the install prefix:
  share/ament_index/resource_index/packages/machine_ctrl   (package marker)
  share/machine_ctrl/package.xml, share/machine_ctrl/config/**   (machine descriptions, parameters)
  share/machine_ctrl/launch/*.launch.py                     (`ros2 launch machine_ctrl ...`)
  bin/<executable>                 console scripts; pip/setuptools write the installing
                                   interpreter into their first line
  lib/machine_ctrl/<executable>    where `ros2 run` and launch_ros look: lib_scripts/<executable>,
                                   a /bin/sh launcher that execs ../../bin/<executable>, so
                                   the node runs with the interpreter the package was
                                   installed with, whatever `python3` is on PATH
"""
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = 'machine_ctrl'

# One entry per executable; lib_scripts/<name> is its `ros2 run` launcher (kept in step by
# test/test_install_layout.py; dev/ament_layout.py reads this dict for the dev venv).
EXECUTABLES = {
    'machine-ctrl': 'machine_ctrl.app.cli:main',
    'hw_sim_node': 'machine_ctrl.ros.hw_sim_node:main',
    'servo_node': 'machine_ctrl.ros.servo_node:main',
    'dual_stage_node': 'machine_ctrl.ros.dual_stage_node:main',
    'reference_node': 'machine_ctrl.ros.reference_node:main',
    'recorder_node': 'machine_ctrl.ros.recorder_node:main',
    'replay_node': 'machine_ctrl.ros.replay_node:main',
    'view_node': 'machine_ctrl.ros.view_node:main',
    'trajectory_node': 'machine_ctrl.ros.trajectory_node:main',
    'contour_error_node': 'machine_ctrl.ros.contour_error_node:main',
    'compensation_node': 'machine_ctrl.ros.compensation_node:main',
}

# Runtime dependencies: every distribution the code imports (test/test_install_layout.py
# checks the installed Requires-Dist against the imports), plus the DDS layer rclpy needs.
# package.xml names the same dependencies as rosdep keys (test/test_package_metadata.py).
#
# Ranges, not pins. requirements.txt is the lock: the exact set the dev venv and CI install
# and the suite runs against. These ranges say what the package needs, so that it can share an
# environment with other packages: the lower bound is the release series of the lock (older
# releases are untested), the upper bound the next major release (the next minor one for 0.x
# releases, which break on minor releases).
# The ROS 2 wheels (ros-<package> on PyPI, one wheel per ROS package) are held to Jazzy's
# release series X.Y.*: the same names carry other distributions (ros-rclpy 9.1 is Kilted's),
# and the messages and rclpy of two distributions do not mix.
REQUIRES = [
    # ROS 2 Jazzy; [fastrtps] pulls rmw_fastrtps_cpp, the RMW rclpy loads by default
    'ros-rclpy[fastrtps]>=7.1.6,<7.2',
    'ros-ament-index-python>=1.8.1,<1.9',
    'ros-builtin-interfaces>=2.0.3,<2.1',
    'ros-rcl-interfaces>=2.0.3,<2.1',
    'ros-rosgraph-msgs>=2.0.3,<2.1',
    'ros-action-msgs>=2.0.3,<2.1',
    'ros-unique-identifier-msgs>=2.5.0,<2.6',
    'ros-std-msgs>=5.3.6,<5.4',
    'ros-std-srvs>=5.3.6,<5.4',
    'ros-geometry-msgs>=5.3.6,<5.4',
    'ros-sensor-msgs>=5.3.6,<5.4',
    'ros-nav-msgs>=5.3.6,<5.4',
    'ros-trajectory-msgs>=5.3.6,<5.4',
    'ros-diagnostic-msgs>=5.3.6,<5.4',
    # numerics, kinematics, planning
    'numpy>=2.4,<3',
    'scipy>=1.17,<2',
    'pin>=4.1,<5',  # Pinocchio (import pinocchio)
    'ruckig>=0.19,<0.20',
    'numba>=0.68.1,<0.69',  # compiled: Algorithm 1's inner loop, the offline runner's loop, the contour truth
    # recording and analysis
    'mcap>=1.6,<2',
    'mcap-ros2-support>=0.6,<0.7',  # import mcap_ros2
    'zstandard>=0.25,<0.26',  # machine_ctrl/recording/mcap_file.py compresses the chunks
    'matplotlib>=3.11,<4',
    'PyYAML>=6.0,<7',  # import yaml
    # identification
    'nfoursid>=1.0.2,<1.1',  # N4SID (machine_ctrl/identification)
    'pandas>=3.1,<4',  # nfoursid's input, imported by machine_ctrl/identification
    # live view
    'foxglove-sdk>=0.30.3,<0.31',  # import foxglove (machine_ctrl/view)
]
EXTRAS = {
    'test': ['pytest>=9.2', 'rosbags>=0.11.9,<0.12',  # rosbags: an independent bag reader for the tests
             'pytest-xdist>=3.8,<4',  # dev/test: two workers, one graph scope each (test/conftest.py)
             'hypothesis>=6.170,<7',  # property-based tests: test_fuzz_graph.py (the graph), test_tracker.py
             'websockets>=17.4,<18',  # test/test_view.py: a Foxglove WebSocket client
             'py-spy>=0.4.3,<0.5'],  # node_common: a shutdown that hangs prints its native stacks
    'bench': ['toppra>=0.6.10,<0.7'],  # bench/feed_vs_toppra.py
}


def _share_data_files(folder, pattern='**/*'):
    """(share/machine_ctrl/<dir>, [files]) for every file of folder matching pattern; none
    when the folder does not exist."""
    by_dir = {}
    for f in sorted(Path(folder).glob(pattern)):
        if f.is_file() and '__pycache__' not in f.parts:
            by_dir.setdefault(str(Path('share', PACKAGE, f.parent)), []).append(str(f))
    return sorted(by_dir.items())


setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(include=['machine_ctrl*', 'trajectory*', 'compensation*', 'hw_sim*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('lib/' + PACKAGE, [f'lib_scripts/{name}' for name in EXECUTABLES]),
        *_share_data_files('config'),
        *_share_data_files('launch', '*.launch.py'),
    ],
    python_requires='>=3.11',
    install_requires=REQUIRES,
    extras_require=EXTRAS,
    zip_safe=False,
    maintainer='machine_ctrl maintainers',
    maintainer_email='maintainers@machine-ctrl.invalid',
    description='Controller for multi-axis machine tools with redundant and dual-stage drives',
    license='Apache-2.0',
    entry_points={'console_scripts': [f'{name} = {target}' for name, target in EXECUTABLES.items()]},
)
