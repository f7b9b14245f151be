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
