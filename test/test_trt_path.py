"""The Eq. (35) test path of Sencer section 4 on trt_5axis (trajectory/sencer_path.py), and
that the completed trt_5axis config runs it on the offline runner."""
import math

import numpy as np
import pytest

from limit_checks import assert_reference_within_limits, assert_within_limits

from hw_sim.offline import run
from trajectory.sencer_path import ACCELERATION, FEED, sencer_reference


@pytest.fixture(scope='module')
def reference(trt):
    return sencer_reference(trt)


def test_tool_path_is_eq35_with_the_inverse_tangent(trt_kin, reference):
    """FK of the axis references gives Eq. (35)'s tool tip; Eq. (3) on the tool axis gives back
    a = -asin(sin l / sqrt 5) and c = -atan(cos l / sqrt 5) (not -tan, the printed typo)."""
    poses = [trt_kin.forward(q) for q in reference.position[::50]] + [trt_kin.forward(reference.position[-1])]
    p = np.array([x[0] for x in poses])
    o = np.array([x[1] for x in poses])
    l = p[:, 2] / 0.015                                       # P_z = 15 l mm
    assert np.allclose(p[:, 0], 0.015 * np.cos(l) + 0.005 * np.sin(l), atol=1e-12)
    assert np.allclose(p[:, 1], 0.015 * np.sin(l) - 0.005 * np.cos(l), atol=1e-12)
    assert np.allclose(-np.arcsin(o[:, 2]), -np.arcsin(np.sin(l) / math.sqrt(5)), atol=1e-12)
    assert np.allclose(np.arctan2(o[:, 0], o[:, 1]), -np.arctan(np.cos(l) / math.sqrt(5)), atol=1e-12)
    assert abs(l[0]) < 1e-12 and abs(l[-1] - 4 * math.pi) < 1e-10


def test_feed_acceleration_and_axis_limits(trt, trt_kin, reference):
    tip = np.array([trt_kin.forward(q)[0] for q in reference.position])
    steps = np.linalg.norm(np.diff(tip, axis=0), axis=1)
    assert steps.sum() == pytest.approx(0.27387, abs=1e-5)          # section 4: 273.87 mm
    speed = steps / trt.control_period
    assert speed.max() == pytest.approx(FEED, rel=1e-3)              # 50 mm/s cruise
    assert np.abs(np.diff(speed)).max() / trt.control_period <= ACCELERATION
    # the axis limits checked apart from the generator's own limit_ratios (which tuned the ramp):
    assert_within_limits(trt, reference.position)              # the positions, differenced
    assert_reference_within_limits(trt, reference, tolerance=1.0)    # the streamed v, a: the generator keeps them <= 1
    fd = np.diff(reference.position, axis=0) / trt.control_period    # velocities are the positions' rates
    assert np.abs(fd - (reference.velocity[1:] + reference.velocity[:-1]) / 2).max() < 3e-4


def test_trt_runs_the_path_with_error_peaks_at_rotary_reversals(trt, reference):
    """Coulomb friction on a and c: the tracking error of each rotary axis peaks within
    0.15 s after one of its velocity reversals (Sencer section 4): after, not before."""
    record = run(trt, reference)
    assert record.fault is None
    error = np.abs(reference.position - record.true)
    assert error[:, :3].max() < 20e-6                                # linear axes: um
    for axis in (3, 4):
        v = reference.velocity[:, axis]
        reversals = np.flatnonzero(np.sign(v[1:]) * np.sign(v[:-1]) < 0)
        peak = int(np.argmax(error[:, axis]))
        assert len(reversals) >= 3
        after = peak - (reversals + 1)           # reversals: the last sample before the sign changes
        assert np.any((after >= 0) & (after * trt.control_period < 0.15)), (peak, reversals)
        assert error[peak, axis] > 5 * np.median(error[:, axis])
