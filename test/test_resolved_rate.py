"""The compiled resolved rate (trajectory/resolved_rate.py): its kinematics against
Pinocchio's on every machine, and Algorithm 1 compiled against the interpreted loop of
trajectory/redundancy.py on Pinocchio's kinematics (an independent route to the same
numbers): the same configurations and rates within the rounding the integration grows, the
same breakdown named at the same place."""
from __future__ import annotations

import numpy as np
import pytest
from test_redundancy import XY, circle, tilted_helix

from machine_ctrl.model.kinematics import Kinematics
from trajectory import toolpath
from trajectory.redundancy import RedundancySettings, ResolutionFailed, initial_configuration, resolve
from trajectory.resolved_rate import pose_jacobian
from trajectory.spline import ArcLengthPath


class Interpreted:
    """A machine's kinematics without packed chains: resolve runs its interpreted loop on
    Pinocchio's calls."""

    def __init__(self, kinematics):
        self.kinematics = kinematics
        self.forward, self.forward_and_jacobian = kinematics.forward, kinematics.forward_and_jacobian

    def packed_chains(self):
        return None


@pytest.mark.parametrize('name', ['micromill', 'trt', 'fts_lathe', 'robot_piezo'])
def test_the_chain_kinematics_are_pinocchios(name, request):
    machine = request.getfixturevalue(name)
    kinematics = Kinematics.from_config(machine)
    chains = kinematics.packed_chains()
    rng = np.random.default_rng(3)
    for q in rng.uniform(-1.0, 1.0, (100, len(machine.axes))):     # 1 m / 1 rad: far beyond the strokes too
        p, o, jac = kinematics.forward_and_jacobian(q)
        p2, o2, jac2 = pose_jacobian(chains, q)
        np.testing.assert_allclose(p2, p, rtol=0, atol=2e-15)
        np.testing.assert_allclose(o2, o, rtol=0, atol=2e-15)
        np.testing.assert_allclose(jac2, jac, rtol=0, atol=2e-15)


def both(path, kinematics, machine, settings=None, q0=None):
    return (resolve(path, kinematics, machine, settings, q0),
            resolve(path, Interpreted(kinematics), machine, settings, q0))


FINE_LINEAR = ('x_f', 'y_f', 'z_f')


@pytest.mark.parametrize('case', ['helix, every axis', 'helix, c_f still', 'helix, fine x y z still',
                                  'circle, x-y axes only (rank 2)'])
def test_a_path_resolves_as_the_interpreted_loop_resolves_it(micromill, micromill_kin, case):
    tip = micromill_kin.forward(np.array(micromill.home))[0]
    if case.startswith('circle'):
        # thesis §3.4: the 4 mm x-y circle on x_c, y_c, x_f, y_f: a rank-2 task (the SVD branch)
        path, settings = circle(4e-3, tip, turns=0.25), RedundancySettings(active_axes=XY)
    else:
        frozen = {'helix, every axis': (), 'helix, c_f still': ('c_f',), 'helix, fine x y z still': FINE_LINEAR}[case]
        path = tilted_helix(2e-3, 0.5e-3, 0.5, tip + np.array([-2e-3, 0, -0.5e-3]))
        settings = RedundancySettings(active_axes=tuple(a for a in micromill.axis_names if a not in frozen))
    compiled, interpreted = both(path, micromill_kin, micromill, settings)
    assert len(compiled.s) > 150
    np.testing.assert_array_equal(compiled.s, interpreted.s)
    # rounding, grown by the integration and by the stencils' 1/ds^k (measured on the whole
    # helix: q 4e-17 m, then 5e-14, 3e-12 and 3e-11 of each output's largest value)
    np.testing.assert_allclose(compiled.q, interpreted.q, rtol=0, atol=1e-15)
    for got, want in ((compiled.dq, interpreted.dq), (compiled.ddq, interpreted.ddq),
                      (compiled.dddq, interpreted.dddq)):
        assert np.abs(got - want).max() <= 1e-9 * np.abs(want).max()
    assert compiled.max_position_error == pytest.approx(interpreted.max_position_error, rel=0, abs=1e-15)
    assert compiled.max_orientation_error == pytest.approx(interpreted.max_orientation_error, rel=0, abs=1e-15)


class Poisoned:
    """A path whose dP/ds is NaN from half its length on: rates that are not finite."""

    def __init__(self, path):
        self.path, self.length, self.knot_s = path, path.length, path.knot_s

    def tangents(self, s):
        (p, o), (dp, do) = self.path.tangents(s)
        dp = np.array(dp)
        dp[np.asarray(s) > self.length / 2] = np.nan
        return [(p, o), (dp, do)]


def arc_beside_home(micromill, micromill_kin, offset):
    """A half circle of 1 mm radius moving the tool tip 2 mm in +x, from `offset` (m) in +x
    beside the home tool tip."""
    tip = micromill_kin.forward(np.array(micromill.home))[0]
    th = np.linspace(0.0, np.pi, 24)
    p = np.column_stack([tip[0] + offset + 1e-3 * (1 - np.cos(th)), tip[1] + 1e-3 * np.sin(th), np.full(24, tip[2])])
    return ArcLengthPath.fit(toolpath.from_arrays(p, np.tile([0.0, 0.0, 1.0], (24, 1))))


@pytest.mark.filterwarnings('ignore:invalid value encountered:RuntimeWarning')   # the interpreted loop's NaN
def test_rates_that_are_not_finite_are_named_as_the_interpreted_loop_names_them(micromill, micromill_kin):
    # numpy carries NaN through the interpreted loop's solves; the compiled loop's LAPACK
    # refuses it: it stops there with NaN rows, and the breakdown is named alike
    path = Poisoned(arc_beside_home(micromill, micromill_kin, 0.0))
    failures = []
    for kinematics in (micromill_kin, Interpreted(micromill_kin)):
        with pytest.raises(ResolutionFailed) as failed:
            resolve(path, kinematics, micromill)
        failures.append(failed.value)
    compiled, interpreted = failures
    assert compiled.kind == interpreted.kind
    assert compiled.s == interpreted.s and compiled.s == pytest.approx(path.length / 2, abs=2 * 20e-6)
    assert compiled.reason == interpreted.reason


def test_a_breakdown_is_named_where_the_interpreted_loop_names_it(micromill, micromill_kin):
    # 2 mm in +x from 48.5 mm beside the home tool tip: x_c (+-50 mm) runs into its stroke
    # end midway and the integration breaks down there (reach.check, which refuses this
    # before resolving, is not in the way)
    path = arc_beside_home(micromill, micromill_kin, 0.0485)
    q0 = initial_configuration(path, micromill_kin, micromill)
    failures = []
    for kinematics in (micromill_kin, Interpreted(micromill_kin)):
        with pytest.raises(ResolutionFailed) as failed:
            resolve(path, kinematics, micromill, q0=q0)
        failures.append(failed.value)
    compiled, interpreted = failures
    assert compiled.kind == interpreted.kind == 'out_of_stroke'
    assert compiled.s == interpreted.s and 1e-3 < compiled.s < path.length
    assert compiled.reason == interpreted.reason
    assert 'between points 12 and 13' in compiled.reason and 'x_c at -0.0494' in compiled.reason
