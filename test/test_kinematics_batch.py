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


def trt_closed_form(q):
    """P and O of trt_5axis by hand from its URDF: the table x, y, then a about x and c about z,
    the workpiece 20 mm up the c axis; the tool tip 70 mm below z, its z axis along base +y.
    P = R^T (p_tool - p_workpiece), O = R^T e_y, R = Rx(a) Rz(c) (Sencer Eqs. (4), (7))."""
    x, y, z, a, c = np.asarray(q, float).T
    zero, one = np.zeros_like(a), np.ones_like(a)
    rx = np.array([[one, zero, zero], [zero, np.cos(a), -np.sin(a)], [zero, np.sin(a), np.cos(a)]])
    rz = np.array([[np.cos(c), -np.sin(c), zero], [np.sin(c), np.cos(c), zero], [zero, zero, one]])
    rotation = np.einsum('ijn,jkn->nik', rx, rz)
    tool = np.column_stack((zero, zero, z - 0.070)) - np.column_stack((x, y, zero))
    p = np.einsum('nji,nj->ni', rotation, tool) - [0.0, 0.0, 0.020]
    o = np.einsum('nji,j->ni', rotation, [0.0, 1.0, 0.0])
    return p, o


def test_a_machine_the_walk_does_not_take_gets_forward_row_by_row(trt):
    """Without the walked chains (a joint that is not axis-aligned), forward_many takes
    forward (Pinocchio) on each row: the pose of each row, in order, against the machine's
    closed form (within rounding: |P| <= 0.6 m)."""
    kinematics = Kinematics.from_config(trt)
    kinematics._chains = None
    q = random_configurations(trt, 20, seed=4)
    positions, axes = kinematics.forward_many(q)
    p, o = trt_closed_form(q)
    assert positions.shape == axes.shape == (20, 3)
    np.testing.assert_allclose(positions, p, rtol=0, atol=1e-15)
    np.testing.assert_allclose(axes, o, rtol=0, atol=1e-15)
    one, _ = kinematics.forward_many(trt.home)
    np.testing.assert_allclose(one, trt_closed_form(np.atleast_2d(trt.home))[0], rtol=0, atol=1e-15)
