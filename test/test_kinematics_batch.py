"""Kinematics.forward_many (every row of a chunk at once, numpy) against Kinematics.forward
(Pinocchio, row by row) on every machine: the same P and O within rounding."""
import numpy as np
import pytest
from conftest import random_configurations

from machine_ctrl.model.config import load_machine
from machine_ctrl.model.kinematics import Kinematics


@pytest.mark.parametrize('name', ['micromill_9axis', 'trt_5axis', 'fts_lathe', 'robot_piezo'])
def test_forward_many_equals_forward_row_by_row(name):
    machine = load_machine(name)
    kinematics = Kinematics.from_config(machine)
    q = random_configurations(machine, 400, seed=3)
    positions, axes = kinematics.forward_many(q)
    rows = [kinematics.forward(row) for row in q]
    assert positions.shape == axes.shape == (400, 3)
    np.testing.assert_allclose(positions, [p for p, _ in rows], rtol=0, atol=1e-15)
    np.testing.assert_allclose(axes, [o for _, o in rows], rtol=0, atol=1e-15)


def test_forward_many_takes_one_row_and_refuses_the_wrong_width(trt_kin, trt):
    p, o = trt_kin.forward_many(trt.home)
    np.testing.assert_allclose(p[0], trt_kin.forward(trt.home)[0], atol=1e-15)
    with pytest.raises(ValueError, match='expected rows of 5 axis positions'):
        trt_kin.forward_many(np.zeros((2, 4)))


def test_a_machine_the_walk_does_not_take_gets_forward_row_by_row(trt):
    """Without the walked chains (a joint that is not axis-aligned), forward_many is
    forward on each row: the same bits."""
    kinematics = Kinematics.from_config(trt)
    kinematics._chains = None
    q = random_configurations(trt, 20, seed=4)
    positions, axes = kinematics.forward_many(q)
    assert np.array_equal(positions, [kinematics.forward(row)[0] for row in q])
    assert np.array_equal(axes, [kinematics.forward(row)[1] for row in q])
