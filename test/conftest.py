import functools
import re
from pathlib import Path

import numpy as np
import pytest

from machine_ctrl.model.config import load_machine
from machine_ctrl.model.kinematics import Kinematics
pytest_plugins = ['ros_fixtures']


@pytest.fixture(scope='session')
def micromill():
    return load_machine('micromill_9axis')


@pytest.fixture(scope='session')
def trt():
    return load_machine('trt_5axis')


@pytest.fixture(scope='session')
def fts_lathe():
    return load_machine('fts_lathe')


@pytest.fixture(scope='session')
def robot_piezo():
    return load_machine('robot_piezo')


@pytest.fixture(scope='session')
def micromill_kin(micromill):
    return Kinematics.from_config(micromill)


@pytest.fixture(scope='session')
def trt_kin(trt):
    return Kinematics.from_config(trt)


def random_configurations(machine, count, seed, continuous_range=2 * np.pi):
    """Uniform in-stroke configurations; unlimited axes span +-continuous_range."""
    rng = np.random.default_rng(seed)
    lo = np.array([a.stroke[0] if a.stroke else -continuous_range for a in machine.axes])
    hi = np.array([a.stroke[1] if a.stroke else continuous_range for a in machine.axes])
    return lo + (hi - lo) * rng.random((count, len(machine.axes)))


def central_difference_jacobian(f, q, h=1e-6):
    columns = []
    for i in range(len(q)):
        dq = np.zeros(len(q))
        dq[i] = h
        columns.append((f(q + dq) - f(q - dq)) / (2 * h))
    return np.column_stack(columns)


# A module that starts ROS nodes names ros_env or a fixture built on it (test/ros_fixtures.py),
# or the bench's bare rclpy ring (test_bench_ros_chain.py, which leases a domain of its own).
_ROS_FIXTURES = re.compile(r'\b(ros_env|rclpy_context|ros_node|ros_supervisor|ros_chain)\b')


@functools.lru_cache(maxsize=None)
def _starts_ros(path: Path) -> bool:
    return bool(_ROS_FIXTURES.search(path.read_text()))


# Graph modules whose checks are results of lock-step runs (bit identity, recorded bags,
# refusals and read-backs), none of a wall-clock watchdog, a stall or a killed process.
# They make a second graph scope, run beside the first; the ROS-free modules fill in after
# either (one busy core: the one graph scope took 960 s, on the critical path, while the
# ROS-free modules took 369 s; split, 702 s and 423 + 415 s: pytest 971 s -> 786 s).
_LOCKSTEP_GRAPHS = frozenset({
    'test_ros_parameters', 'test_freeform_graph', 'test_determinism', 'test_gcode_graph', 'test_graph',
    'test_view', 'test_robot_piezo_graph', 'test_contour_node', 'test_compensation_graph', 'test_parameters'})


def pytest_xdist_make_scheduler(config, log):
    """dev/test runs the suite in two pytest-xdist workers (`-n 2`). The modules that start
    ROS nodes make two scopes (above); one worker runs a scope test after test, so at most
    two graphs run at a time, each in its own ROS domain (a session's lease), and the graphs
    of fault detection only ever beside one of lock-step results or a ROS-free module. A
    module stays in one worker, so its module fixtures (an experiment run, an installed
    prefix) are made once. (pytest-xdist's own --dist loadgroup does not group under pytest
    9, whose node ids it can no longer rename.)"""
    from xdist.scheduler import LoadScopeScheduling

    class GraphsInOneWorker(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split('::')[0]
            if not _starts_ros(config.rootpath / module):
                return module
            return 'lockstep_graphs' if Path(module).stem in _LOCKSTEP_GRAPHS else 'ros_graph'
    return GraphsInOneWorker(config, log)


def pytest_collection_modifyitems(config, items):
    """The scheduler's reading of a module (above) must hold: a test that uses ros_env in a
    module the scheduler takes for ROS-free would run a graph beside another."""
    missed = sorted({item.nodeid.split('::')[0] for item in items
                     if 'ros_env' in getattr(item, 'fixturenames', ())
                     and not _starts_ros(config.rootpath / item.nodeid.split('::')[0])})
    if missed:
        raise pytest.UsageError(f'{", ".join(missed)}: tests use ros_env through a fixture that test/conftest.py '
                                '_ROS_FIXTURES does not name; add it there')
