"""Error-augmented kinematics (compensation/error_model.py, thesis Eqs. 5.1-5.7) against the
ideal Pinocchio kinematics and against an exact rigid-body chain written out here."""
import numpy as np
import pytest
from conftest import central_difference_jacobian, random_configurations
from scipy.spatial.transform import Rotation

from compensation.error_map import AxisErrors, ErrorMap, Squareness, load_error_map
from compensation.error_model import ErrorKinematics
from hw_sim.simulator import true_geometry
from machine_ctrl.model.errors import ConfigError

FINE = ('x_f', 'y_f', 'z_f', 'a_f', 'b_f', 'c_f')
# URDF offsets (assumed there), m; see test_kinematics_micromill.py
L_YZ, L_XZ, L_S, Z_F0, L_R, L_W = 0.060, 0.040, 0.025, 0.002, 0.015, 0.010
Z_TOOL, L_SPY, L_DOWN = 0.262, 0.002, 0.100


def constant_map(values):
    """axis -> 6 constant errors [dx dy dz ex ey ez]."""
    return ErrorMap({a: AxisErrors((-1.0, 1.0), {n: (float(v),) for n, v in zip(('dx', 'dy', 'dz', 'ex', 'ey', 'ez'), e)})
                     for a, e in values.items()})


def exact_error(e):
    """Exact rigid transform for errors e: rotation by the rotation vector (ex, ey, ez)
    (first order: Eq. 5.1's I + skew), translation (dx, dy, dz)."""
    t = np.eye(4)
    t[:3, :3] = Rotation.from_rotvec(e[3:]).as_matrix()
    t[:3, 3] = e[:3]
    return t


def trans(x=0.0, y=0.0, z=0.0):
    t = np.eye(4)
    t[:3, 3] = x, y, z
    return t


def rot(axis, angle):
    t = np.eye(4)
    t[:3, :3] = Rotation.from_euler(axis, angle).as_matrix()
    return t


def exact_tip(q, e):
    """Eqs. (5.4)-(5.7) with exact error transforms, the chain of the micromill URDF."""
    x_c, y_c, z_c, x_f, y_f, z_f, a_f, b_f, c_f = q
    w = (trans(z=L_YZ) @ trans(y=y_c) @ exact_error(e['y_c']) @ trans(z=L_XZ) @ trans(x=x_c)
         @ exact_error(e['x_c']) @ trans(z=L_S) @ trans(x=x_f) @ trans(y=y_f) @ trans(z=Z_F0 + z_f)
         @ rot('x', a_f) @ rot('y', b_f) @ rot('z', c_f) @ trans(z=L_R + L_W))
    t = trans(z=Z_TOOL + z_c) @ exact_error(e['z_c']) @ trans(y=L_SPY, z=-L_DOWN)
    return (np.linalg.inv(w) @ t)[:3, 3]


@pytest.fixture(scope='module')
def configurations(micromill):
    return random_configurations(micromill, 300, seed=3)


def test_zero_errors_equal_the_ideal_kinematics(micromill, micromill_kin, configurations):
    zero = constant_map({a: np.zeros(6) for a in ('x_c', 'y_c', 'z_c')})
    ideal = np.array([micromill_kin.tool_pose(q) for q in configurations])
    for error_map in (None, zero):
        model = ErrorKinematics.from_config(micromill, error_map, micromill_kin)
        rotation, position = model.tool_poses(configurations)
        assert np.abs(position - ideal[:, :3, 3]).max() <= 1e-15
        assert np.abs(rotation - ideal[:, :3, :3]).max() <= 1e-15


def test_small_errors_match_the_exact_chain_to_first_order(micromill, micromill_kin, configurations):
    rng = np.random.default_rng(7)
    errors = {a: rng.uniform(-1, 1, 6) * np.array([2e-6] * 3 + [2e-5] * 3) for a in ('x_c', 'y_c', 'z_c')}
    model = ErrorKinematics.from_config(micromill, constant_map(errors), micromill_kin)
    ideal = ErrorKinematics.from_config(micromill, None, micromill_kin)
    got = model.positions(configurations[:50])
    effect = got - ideal.positions(configurations[:50])
    assert np.abs(effect).max() > 1e-6                       # the errors move the tip by um
    for q, p in zip(configurations[:50], got):
        # second-order terms: (2e-5 rad)^2 x 0.3 m ~ 1e-10 m
        assert np.abs(p - exact_tip(q, errors)).max() < 5e-10


def test_squareness_tilts_the_direction_of_motion(micromill, micromill_kin):
    gamma = 20e-6
    model = ErrorKinematics.from_config(micromill, ErrorMap({}, (Squareness('x_c', 'z', gamma),)), micromill_kin)
    ideal = ErrorKinematics.from_config(micromill, None, micromill_kin)
    q = np.zeros((2, 9))
    q[1, 0] = 0.04
    delta = model.positions(q) - ideal.positions(q)
    # x_c moves along (1, gamma, 0): the workpiece goes +gamma*x in y, the tip relative to it -gamma*x
    np.testing.assert_allclose(delta[1], [0.0, -gamma * 0.04, 0.0], atol=1e-18)
    np.testing.assert_allclose(delta[0], 0.0, atol=1e-18)


def test_compensating_jacobian(micromill, micromill_kin, configurations):
    ideal = ErrorKinematics.from_config(micromill, None, micromill_kin)
    _, jc = ideal.positions_and_jacobian(configurations, FINE)
    for q, j in zip(configurations, jc):
        np.testing.assert_allclose(j, micromill_kin.jacobian(q)[:3, 3:], rtol=0, atol=1e-13)
    true_map = load_error_map(micromill.simulation.error_map_path(micromill.yaml_path), micromill.axis_names)
    model = ErrorKinematics.from_config(micromill, true_map, micromill_kin)
    _, jc = model.positions_and_jacobian(configurations[:20], FINE)
    for q, j in zip(configurations[:20], jc):
        def tip(fine, q=q):
            return model.positions(np.concatenate((q[:3], fine)))[0]
        np.testing.assert_allclose(j, central_difference_jacobian(tip, q[3:], 1e-6), rtol=0, atol=1e-9)


def test_hw_sim_ground_truth_has_the_configured_errors(micromill, micromill_kin, trt, trt_kin):
    truth = true_geometry(micromill, micromill_kin)
    q = np.zeros(9)
    q[:3] = 0.03, -0.03, 0.05
    assert 0.5e-6 < np.abs(truth(q)[:3, 3] - micromill_kin.tool_pose(q)[:3, 3]).max() < 20e-6
    q5 = np.array([0.01, 0.02, -0.01, 0.1, 0.3])
    assert (true_geometry(trt, trt_kin)(q5) == trt_kin.tool_pose(q5)).all()       # no map: ideal


@pytest.mark.parametrize('text, problem', [
    ('kind: other\naxes: {}\n', 'kind: must be geometric_error_map'),
    ('kind: geometric_error_map\naxes: {w_c: {range: [0, 1]}}\n', 'axes.w_c: unknown axis'),
    ('kind: geometric_error_map\naxes: {x_c: {range: [1, 0]}}\n', 'axes.x_c.range: lo must be < hi'),
    ('kind: geometric_error_map\naxes: {x_c: {range: [0, 1], dx: [a]}}\n', 'axes.x_c.dx.0: must be a number'),
    ('kind: geometric_error_map\naxes: {x_c: {range: [0, 1], dq: [1]}}\n', 'unknown key(s): dq'),
    ('kind: geometric_error_map\naxes: {}\nsquareness: [{axis: x_c, about: w, angle: 1}]\n', 'about: must be one of'),
])
def test_bad_error_maps_are_refused_with_one_line(tmp_path, micromill, text, problem):
    path = tmp_path / 'map.yaml'
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_error_map(path, micromill.axis_names)
    assert problem in str(info.value) and str(path) in str(info.value) and '\n' not in str(info.value)
