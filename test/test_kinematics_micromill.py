"""9-axis micromill kinematics (Pinocchio, from the URDF) against the thesis chain
Eqs. (3.1)-(3.5) multiplied out independently here in numpy."""
import numpy as np
import pytest
from conftest import central_difference_jacobian, random_configurations

from machine_ctrl.model.kinematics import task_jacobian

# The offsets written in config/machines/micromill_9axis.urdf (all assumed there), in m.
L_YZ, L_XZ, L_S, Z_F0, L_R, L_W, Z_C0 = 0.060, 0.040, 0.025, 0.002, 0.015, 0.010, 0.010
L_SPY, L_SPZ, L_T = 0.002, 0.080, 0.020
L_0Z = L_XZ + L_YZ + L_S + Z_F0 + L_R + L_W + Z_C0 + L_SPZ + L_T  # Eq. (3.3)


def trans(x=0.0, y=0.0, z=0.0):
    t = np.eye(4)
    t[:3, 3] = x, y, z
    return t


def rot(axis, angle):
    c, s = np.cos(angle), np.sin(angle)
    t = np.eye(4)
    i, j = {'x': (1, 2), 'y': (2, 0), 'z': (0, 1)}[axis]
    t[i, i], t[i, j], t[j, i], t[j, j] = c, -s, s, c
    return t


def thesis_chain(q):
    """Eqs. (3.1)-(3.5). The tip is at -L_t in the tool frame (see the URDF header: the
    printed +L_t contradicts Eq. (3.3) and Eq. (3.8))."""
    x_c, y_c, z_c, x_f, y_f, z_f, a_f, b_f, c_f = q
    b_t_w = (trans(y=y_c, z=L_YZ) @ trans(x=x_c, z=L_XZ) @ trans(z=L_S) @ trans(x=x_f)
             @ trans(y=y_f) @ trans(z=z_f + Z_F0) @ rot('x', a_f) @ rot('y', b_f) @ rot('z', c_f)
             @ trans(z=L_R) @ trans(z=L_W))                                           # (3.1)
    b_t_t = trans(z=z_c + L_0Z) @ trans(y=L_SPY, z=-L_SPZ)                            # (3.2)
    w_t_t = np.linalg.inv(b_t_w) @ b_t_t                                              # (3.4)
    tip = w_t_t @ np.array([0.0, 0.0, -L_T, 1.0])                                     # (3.5)
    return w_t_t, tip[:3], w_t_t[:3, :3] @ np.array([0.0, 0.0, 1.0])


def printed_orientation(q):
    """Eqs. (3.9)-(3.11) as printed (exact, seed-notes.md)."""
    sa, ca, sb, cb, sc, cc = (f(v) for v in q[6:9] for f in (np.sin, np.cos))
    return np.array([sa * sc - ca * cc * sb, cc * sa + ca * sb * sc, ca * cb])


def corrected_position(q):
    """seed-notes.md: P = R^T d - [0, 0, L_r + L_w], R = Rx Ry Rz,
    d = (-x_c - x_f, L_sp,y - y_c - y_f, z_c + L_r + L_w + z_c0 - z_f)."""
    x_c, y_c, z_c, x_f, y_f, z_f, a_f, b_f, c_f = q
    r = (rot('x', a_f) @ rot('y', b_f) @ rot('z', c_f))[:3, :3]
    d = np.array([-x_c - x_f, L_SPY - y_c - y_f, z_c + L_R + L_W + Z_C0 - z_f])
    return r.T @ d - np.array([0.0, 0.0, L_R + L_W])


@pytest.fixture(scope='module')
def configurations(micromill):
    return random_configurations(micromill, 1000, seed=1)


def test_position_and_orientation_match_thesis_chain(micromill_kin, configurations):
    worst_p = worst_o = 0.0
    for q in configurations:
        _, p_ref, o_ref = thesis_chain(q)
        p, o = micromill_kin.forward(q)
        worst_p = max(worst_p, np.abs(p - p_ref).max())
        worst_o = max(worst_o, np.abs(o - o_ref).max())
    assert worst_p <= 1e-12
    assert worst_o <= 1e-12


def test_printed_orientation_and_corrected_position(micromill_kin, configurations):
    for q in configurations[:200]:
        p, o = micromill_kin.forward(q)
        np.testing.assert_allclose(o, printed_orientation(q), rtol=0, atol=1e-12)
        np.testing.assert_allclose(p, corrected_position(q), rtol=0, atol=1e-12)


def test_tool_pose_is_the_chain_transform(micromill_kin, configurations):
    for q in configurations[:100]:
        tip_frame = thesis_chain(q)[0] @ trans(z=-L_T)   # our tool frame sits at the tip
        np.testing.assert_allclose(micromill_kin.tool_pose(q), tip_frame, rtol=0, atol=1e-12)


def test_jacobian_matches_central_differences(micromill_kin, configurations):
    def pose(q):
        return np.concatenate(micromill_kin.forward(q))

    worst = 0.0
    for q in configurations[:300]:
        p, o, jac = micromill_kin.forward_and_jacobian(q)
        np.testing.assert_array_equal(np.concatenate((p, o)), pose(q))
        fd = central_difference_jacobian(pose, q)
        worst = max(worst, np.linalg.norm(jac - fd) / np.linalg.norm(jac))
    assert worst <= 1e-6


def test_continuous_axis_is_periodic_and_unbounded(micromill_kin):
    q = np.array([0.01, -0.02, 0.03, 5e-5, -5e-5, 2e-5, 0.004, -0.003, 0.7])
    shifted = q.copy()
    shifted[8] += 6 * np.pi
    np.testing.assert_allclose(micromill_kin.tool_pose(shifted), micromill_kin.tool_pose(q), atol=1e-12)
    # one Jacobian column per axis even though c_f has two Pinocchio coordinates
    assert micromill_kin.jacobian(q).shape == (6, 9)
    assert micromill_kin.model.nq == 10


def test_jacobian_rank_and_task_jacobian(micromill_kin, configurations):
    for q in configurations[:50]:
        _, o, jac = micromill_kin.forward_and_jacobian(q)
        np.testing.assert_allclose(o @ jac[3:], 0.0, atol=1e-12)   # d|O|^2/dq = 0
        singular_values = np.linalg.svd(jac, compute_uv=False)
        assert singular_values[5] <= 1e-12 * singular_values[0]     # rank <= 5: JJ^T singular
        task = task_jacobian(jac, o)
        assert task.shape == (5, 9)
        assert np.linalg.matrix_rank(task) == 5
        # the task rows lose nothing: the orientation rows are recovered from them
        basis = np.linalg.svd(jac[3:])[0][:, :2]
        np.testing.assert_allclose(basis @ (basis.T @ jac[3:]), jac[3:], atol=1e-12)


def test_wrong_configuration_length_is_rejected(micromill_kin):
    with pytest.raises(ValueError, match='expected 9 axis positions'):
        micromill_kin.forward(np.zeros(8))


def test_the_pinocchio_configuration_puts_each_axis_in_its_joint_s_slot(micromill_kin):
    """Each one-value joint's slot (model.joints[...].idx_q) holds its axis position as given,
    the continuous c_f's two slots cos and sin of its angle; the vector handed out is the
    caller's own (a later call does not change it)."""
    import math
    q = np.array([0.01, -0.02, 0.03, 5e-5, -5e-5, 2e-5, 0.004, -0.003, 0.7])
    configuration = micromill_kin.pin_configuration(q)
    model = micromill_kin.model
    for name, value in zip(micromill_kin.axis_names, q):
        joint = model.joints[model.getJointId(name)]
        if joint.nq == 1:
            assert configuration[joint.idx_q] == value
        else:
            assert tuple(configuration[joint.idx_q:joint.idx_q + 2]) == (math.cos(value), math.sin(value))
    kept = configuration.copy()
    micromill_kin.forward_and_jacobian(-q)
    micromill_kin.pin_configuration(2 * q)
    assert np.array_equal(configuration, kept)
