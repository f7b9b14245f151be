"""package.xml and setup.py name the same dependencies.

Every runtime requirement of setup.py (REQUIRES, what `pip install .` pulls) is an exec_depend
of package.xml (what rosdep installs for a colcon build) under its rosdep key, and the other
way round; the test extra and the test_depends likewise. Every key is one the ROS rosdep
database resolves (recorded below) or one resource/rosdep.yaml defines.
(test/test_install_layout.py checks that REQUIRES covers every import.)"""
import ast
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import yaml
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]

# PyPI distribution -> rosdep key, for those that are not ROS packages (ros-<name> wheels map to
# the ROS package <name>, dashes to underscores).
DISTRIBUTION_TO_KEY = {
    'numpy': 'python3-numpy',
    'scipy': 'python3-scipy',
    'pyyaml': 'python3-yaml',
    'matplotlib': 'python3-matplotlib',
    'pin': 'pinocchio',  # the ROS package carries the Python bindings (4.1.0 in Jazzy)
    'ruckig': 'python3-ruckig-pip',  # the ROS package ruckig is the C++ library only
    'mcap': 'python3-mcap-pip',
    'zstandard': 'python3-zstandard-pip',  # rosdep/python.yaml at 8468e88 has no key for it
    'nfoursid': 'python3-nfoursid-pip',
    'numba': 'python3-numba-pip',  # pinned to the numpy of the other wheels, as Debian's is not
    'pandas': 'python3-pandas',
    'mcap-ros2-support': 'mcap-ros2-support',  # rosdep's key for it has no python3- prefix
    'pytest': 'python3-pytest',
    'rosbags': 'python3-rosbags-pip',
    'hypothesis': 'python3-hypothesis',
    'foxglove-sdk': 'python3-foxglove-sdk-pip',
    'websockets': 'python3-websockets-pip',
    'pytest-xdist': 'python3-pytest-xdist-pip',
    'py-spy': 'python3-py-spy-pip',
}
# exec_depends with no requirement in setup.py, and why.
PACKAGE_XML_ONLY = {
    'launch': 'share/machine_ctrl/launch/*.launch.py; comes with the ros2 command line, not on PyPI',
    'launch_ros': 'share/machine_ctrl/launch/*.launch.py; comes with the ros2 command line, not on PyPI',
}
# Keys checked to resolve for Jazzy on Ubuntu noble against ros/rosdistro (jazzy/distribution.yaml,
# rosdep/base.yaml, rosdep/python.yaml at 8468e88, 2026-08-22) with `rosdep resolve`.
ROSDISTRO_KEYS = {
    'rclpy', 'ament_index_python', 'builtin_interfaces', 'rcl_interfaces', 'rosgraph_msgs', 'action_msgs',
    'unique_identifier_msgs', 'std_msgs', 'std_srvs', 'geometry_msgs', 'sensor_msgs', 'nav_msgs',
    'trajectory_msgs', 'diagnostic_msgs', 'launch', 'launch_ros', 'pinocchio',
    'python3-numpy', 'python3-scipy', 'python3-yaml', 'python3-matplotlib', 'mcap-ros2-support',
    'python3-pytest', 'python3-rosbags-pip', 'python3-setuptools', 'python3-hypothesis',
    'python3-pandas',     # rosdep/python.yaml at 000730dc (ubuntu: [python3-pandas])
}


def setup_value(name):
    for node in ast.walk(ast.parse((ROOT / 'setup.py').read_text())):
        if isinstance(node, ast.Assign) and getattr(node.targets[0], 'id', '') == name:
            return ast.literal_eval(node.value)
    raise AssertionError(f'setup.py has no {name}')


def setup_version():
    for node in ast.walk(ast.parse((ROOT / 'setup.py').read_text())):
        if isinstance(node, ast.keyword) and node.arg == 'version':
            return ast.literal_eval(node.value)
    raise AssertionError('setup.py has no version')


def key_of(requirement):
    name = re.sub(r'[-_.]+', '-', Requirement(requirement).name).lower()
    if name.startswith('ros-'):
        return name[len('ros-'):].replace('-', '_')
    assert name in DISTRIBUTION_TO_KEY, f'{requirement}: give it a rosdep key in DISTRIBUTION_TO_KEY and package.xml'
    return DISTRIBUTION_TO_KEY[name]


def manifest():
    return ET.parse(ROOT / 'package.xml').getroot()


def tags(tag):
    return [e.text.strip() for e in manifest().iter(tag)]


def local_keys():
    return yaml.safe_load((ROOT / 'resource/rosdep.yaml').read_text())


def test_manifest_is_an_ament_python_package_of_this_version():
    root = manifest()
    assert root.get('format') == '3'
    assert root.findtext('name') == 'machine_ctrl'
    assert root.findtext('version') == setup_version()
    assert root.findtext('export/build_type') == 'ament_python'
    assert tags('buildtool_depend') == ['python3-setuptools']
    assert not tags('depend') and not tags('build_depend'), 'a pure Python package: exec_ and test_depends only'


def test_exec_depends_are_the_runtime_requirements():
    wanted = {key_of(r) for r in setup_value('REQUIRES')} | set(PACKAGE_XML_ONLY)
    exec_depends = tags('exec_depend')
    assert len(exec_depends) == len(set(exec_depends)), 'a key twice'
    assert sorted(set(exec_depends) - wanted) == [], 'exec_depends with no requirement in setup.py REQUIRES'
    assert sorted(wanted - set(exec_depends)) == [], 'setup.py REQUIRES missing from package.xml exec_depends'


def test_test_depends_are_the_test_extra():
    assert sorted(tags('test_depend')) == sorted(key_of(r) for r in setup_value('EXTRAS')['test'])


def test_every_key_resolves():
    keys = set(tags('exec_depend') + tags('test_depend') + tags('buildtool_depend'))
    unknown = sorted(keys - ROSDISTRO_KEYS - set(local_keys()))
    assert not unknown, (f'keys rosdep cannot resolve: {unknown} '
                         '(check ros/rosdistro, or define them in resource/rosdep.yaml)')
    assert not set(local_keys()) & ROSDISTRO_KEYS, 'resource/rosdep.yaml redefines a key of the ROS database'


def test_local_keys_install_the_required_distributions():
    required = {re.sub(r'[-_.]+', '-', Requirement(r).name).lower()
                for r in setup_value('REQUIRES') + setup_value('EXTRAS')['test']}
    for key, platforms in local_keys().items():
        assert re.fullmatch(r'python3-[a-z0-9-]+-pip', key), key
        assert set(platforms) >= {'debian', 'ubuntu'}, key
        for platform, rule in platforms.items():
            (package,) = rule['pip']['packages']
            assert package in required and DISTRIBUTION_TO_KEY[package] == key, (key, platform)
