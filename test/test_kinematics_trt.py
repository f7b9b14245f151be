"""Sencer TRT 5-axis kinematics: Pinocchio model vs Eq. (7)/(4) written here in numpy, and
the closed-form inverse (Eqs. 3 and 6, with the Eq. 6 erratum corrected)."""
import numpy as np
import pytest
from conftest import random_configurations

from machine_ctrl.model.trt_kinematics import TrtInverseKinematics

A2 = 0.070   # m, Sencer section 4
D4 = 0.020   # m, assumed in config/machines/trt_5axis.urdf


def eq7(q):
    x, y, z, a, c = q
    sa, ca, sc, cc = np.sin(a), np.cos(a), np.sin(c), np.cos(c)
    m = np.array([[-cc, -sc * ca, sa * sc], [sc, -cc * ca, sa * cc], [0.0, sa, ca]])
    n = np.array([[0.0, -sc * sa], [0.0, -cc * sa], [-1.0, -ca]])
    return m @ np.array([x, y, z]) + n @ np.array([D4, A2])


def eq4(q):
    a, c = q[3], q[4]
    return np.array([np.cos(a) * np.sin(c), np.cos(a) * np.cos(c), -np.sin(a)])


def eq6_as_printed(p, a, c):
    sa, ca, sc, cc = np.sin(a), np.cos(a), np.sin(c), np.cos(c)
    rotation = np.array([[-cc, sc, 0.0], [-ca * sc, -ca * cc, sa], [sa * sc, sa * cc, ca]])
    return rotation @ p + np.array([[0.0, 0.0], [sa, 0.0], [ca, -1.0]]) @ np.array([D4, A2])


@pytest.fixture(scope='module')
def configurations(trt):
    # |a| < pi/2 keeps Eq. (3) single-valued; c within (-pi, pi] is what atan2 returns
    q = random_configurations(trt, 1000, seed=2, continuous_range=np.pi)
    return q


def test_forward_matches_eq7_and_eq4(trt_kin, configurations):
    for q in configurations:
        p, o = trt_kin.forward(q)
        np.testing.assert_allclose(p, eq7(q), rtol=0, atol=1e-12)
        np.testing.assert_allclose(o, eq4(q), rtol=0, atol=1e-12)


def test_inverse_round_trips(trt_kin, configurations):
    ik = TrtInverseKinematics.from_kinematics(trt_kin)
    assert ik.a2 == pytest.approx(A2, abs=1e-15) and ik.d4 == pytest.approx(D4, abs=1e-15)
    worst = 0.0
    for q in configurations:
        p, o = trt_kin.forward(q)
        q_back = ik.solve(p, o, c_hint=q[4])
        worst = max(worst, np.abs(q_back - q).max())
        p_back, o_back = trt_kin.forward(q_back)
        worst = max(worst, np.abs(p_back - p).max(), np.abs(o_back - o).max())
    assert worst <= 1e-12


def test_eq6_as_printed_is_off_by_2_a2_in_z(trt_kin):
    q = np.array([0.01, -0.02, 0.03, 0.3, -0.4])
    p, _ = trt_kin.forward(q)
    printed = eq6_as_printed(p, q[3], q[4])
    np.testing.assert_allclose(printed[:2], q[:2], atol=1e-12)
    assert printed[2] - q[2] == pytest.approx(-2 * A2, abs=1e-12)


def test_continuous_c_follows_the_hint(trt_kin):
    ik = TrtInverseKinematics.from_kinematics(trt_kin)
    q = np.array([0.01, 0.02, -0.01, 0.2, 3.0 + 4 * np.pi])
    q_back = ik.solve(*trt_kin.forward(q), c_hint=q[4] - 0.1)
    np.testing.assert_allclose(q_back, q, atol=1e-12)
