"""ament_python package machine_ctrl.

Besides the Python packages this installs, under the install prefix:
  share/ament_index/resource_index/packages/machine_ctrl   (package marker)
  share/machine_ctrl/package.xml, share/machine_ctrl/config/*   (machine descriptions)
  bin/<executable>                 console scripts (on PATH in a venv)
  lib/machine_ctrl/<executable>    the same executables where `ros2 run` looks for them
"""
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = 'machine_ctrl'

# One entry per executable; lib_scripts/<name> is its `ros2 run` launcher (kept in step by
# test/test_install_layout.py).
EXECUTABLES = {
    'machine-ctrl': 'machine_ctrl.app.cli:main',
    'hw_sim_node': 'machine_ctrl.ros.hw_sim_node:main',
    'servo_node': 'machine_ctrl.ros.servo_node:main',
    'dual_stage_node': 'machine_ctrl.ros.dual_stage_node:main',
    'reference_node': 'machine_ctrl.ros.reference_node:main',
    'recorder_node': 'machine_ctrl.ros.recorder_node:main',
    'replay_node': 'machine_ctrl.ros.replay_node:main',
    'trajectory_node': 'machine_ctrl.ros.trajectory_node:main',
    'contour_error_node': 'machine_ctrl.ros.contour_error_node:main',
    'compensation_node': 'machine_ctrl.ros.compensation_node:main',
}


def _files(folder):
    return sorted(str(p) for p in Path(folder).rglob('*') if p.is_file())


def _config_data_files():
    by_dir = {}
    for f in _files('config'):
        by_dir.setdefault(str(Path('share', PACKAGE, Path(f).parent)), []).append(f)
    return sorted(by_dir.items())


setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(include=['machine_ctrl*', 'trajectory*', 'compensation*', 'hw_sim*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('lib/' + PACKAGE, [f'lib_scripts/{name}' for name in EXECUTABLES]),
        *_config_data_files(),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    maintainer='machine_ctrl maintainers',
    maintainer_email='maintainers@machine-ctrl.invalid',
    description='Controller for multi-axis machine tools with redundant and dual-stage drives',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={'console_scripts': [f'{name} = {target}' for name, target in EXECUTABLES.items()]},
)
