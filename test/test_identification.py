"""Subspace identification (machine_ctrl/identification/subspace.py; issue [4/8], Sörnmo
section 2.3): a known model's order and poles recovered from its own chirp data, the fit as
VAF, bad data refused with the reason.

The known models are the simulated micro manipulator's axes of section 2.3
(machine_ctrl/experiments/piezo_milling.py: orders 4 / 2 / 5 in x / y / z, the first
eigenfrequency within 33-47 Hz in every axis, a second one in x and z, Fig. 2.5; their
frequencies and dampings assumed, the identified matrices are not printed). The data are made as the thesis made its own: a 10-60 Hz chirp at 1 kHz, output
noise, decimated six times to ~167 Hz."""
import math

import numpy as np
import pytest
from scipy import signal

from machine_ctrl.experiments import piezo_milling
from machine_ctrl.identification.subspace import Status, chirp, identify, select_order, vaf

RATE_HZ, DECIMATION = 1000.0, 6          # Sörnmo section 2.3: 1 kHz, decimated six times
# the simulated axes' modes (Hz, zeta) and z's real pole (Hz), assumed in piezo_milling.AXES
MODELS = {name: (axis.modes, axis.real_pole) for name, axis in piezo_milling.AXES.items()}


def transfer(modes, real_pole_hz):
    """Unit static gain: each mode w^2 / (s^2 + 2 zeta w s + w^2), the real pole p / (s + p)."""
    num, den = np.array([1.0]), np.array([1.0])
    for f, zeta in modes:
        w = 2 * math.pi * f
        num, den = num * w * w, np.polymul(den, [1.0, 2 * zeta * w, w * w])
    if real_pole_hz is not None:
        p = 2 * math.pi * real_pole_hz
        num, den = num * p, np.polymul(den, [1.0, p])
    return num, den


def chirp_data(num, den, seed=1, noise=0.01):
    period = 1.0 / RATE_HZ
    a, b, c, d, _ = signal.cont2discrete(signal.tf2ss(num, den), period, method='zoh')
    u = chirp(10.0, 60.0, 60.0, period)
    _, y, _ = signal.dlsim((a, b, c, d, period), u)
    y = y[:, 0] + noise * np.std(y) * np.random.default_rng(seed).standard_normal(len(u))
    return signal.decimate(u, DECIMATION), signal.decimate(y, DECIMATION), DECIMATION * period


@pytest.mark.parametrize('axis', sorted(MODELS))
def test_a_known_models_order_and_poles_come_back_from_its_chirp_data(axis):
    modes, real_pole = MODELS[axis]
    num, den = transfer(modes, real_pole)
    result = identify(*chirp_data(num, den))
    assert result.ok, result.reason
    assert result.model.order == len(den) - 1                          # 4 / 2 / 5, from the singular values
    true = np.sort(np.abs(np.roots(den)) / (2 * math.pi))              # Hz, every pole
    assert result.model.natural_frequencies() == pytest.approx(true, rel=0.05)
    damped = [f for f, _ in modes]                                     # the modes themselves, closer
    ours = result.model.natural_frequencies()
    for f in damped:
        assert min(abs(ours - f)) / f < 0.01, (f, ours)
    assert result.vaf > 99.0                                           # seed: 92.5 / 99.5 / 97.1 on real data
    s = np.array(result.singular_values)
    assert s[result.model.order - 1] / s[result.model.order] > 10      # the gap the order was read from


def test_the_economy_svd_step_gives_the_librarys_model():
    """identify() replaces one step of nfoursid (the full SVD of a samples-wide matrix) by the
    economy SVD: on a record short enough for the library's own, the same matrices."""
    import pandas as pd
    from nfoursid.nfoursid import NFourSID

    from machine_ctrl.identification.subspace import _n4sid_class
    u, y, _ = chirp_data(*transfer(*MODELS['x']))
    frame = pd.DataFrame({'u': u[:600], 'y': y[:600]})
    models = []
    for cls in (NFourSID, _n4sid_class()):
        n4sid = cls(frame, output_columns=['y'], input_columns=['u'], num_block_rows=6)
        n4sid.subspace_identification()
        models.append(n4sid.system_identification(rank=4)[0])
    # the same matrices up to rounding: the two SVDs take different LAPACK paths, whose rounding
    # depends on the CPU's kernels (4e-11 of each matrix's largest entry on an AMD EPYC, where
    # its small entries missed a purely relative 1e-9): 1e-9 of the matrix's scale
    for name in 'abcd':
        ours, theirs = getattr(models[1], name), getattr(models[0], name)
        assert np.allclose(ours, theirs, rtol=1e-9, atol=1e-9 * np.abs(theirs).max()), name


def test_the_order_is_where_the_singular_values_drop_most():
    assert select_order([10.0, 9.0, 8.0, 0.01, 0.008, 0.007]) == 3
    assert select_order([10.0, 0.1, 0.09, 0.001, 0.0009], max_order=2) == 1
    assert select_order([5.0, 4.0, 1e-3, 0.0, 0.0]) == 3                # noise-free data: the rank


def test_vaf_is_the_share_of_the_output_variance_the_model_explains():
    y = np.sin(np.linspace(0, 20, 500))
    assert vaf(y, y) == 100.0
    assert vaf(y, np.zeros_like(y)) == pytest.approx(0.0, abs=1e-9)
    assert vaf(y, 0.9 * y) == pytest.approx(99.0)


@pytest.mark.parametrize('edit, reason', [
    (lambda u, y: (u[:-1], y), 'input and output must be two series of one length'),
    (lambda u, y: (u, np.where(np.arange(len(y)) == 7, np.nan, y)), 'NaN or inf'),
    (lambda u, y: (u[:50], y[:50]), '50 samples: at least 60 are needed'),
    (lambda u, y: (np.zeros_like(u), y), 'the input is constant or a straight line'),
    (lambda u, y: (np.linspace(0.0, 1.0, len(u)), y), 'the input is constant or a straight line'),
    (lambda u, y: (u, 3.0 + 0.1 * np.arange(len(y))), 'the output is constant or a straight line'),
])
def test_bad_data_is_refused_with_the_reason(edit, reason):
    u, y, period = chirp_data(*transfer(*MODELS['y']))
    result = identify(*edit(u, y), period)
    assert result.status is Status.BAD_DATA and reason in result.reason and result.model is None
    assert identify(u, y, 0.0).status is Status.BAD_DATA
    assert 'order 9 must be an integer within 1..6' in identify(u, y, period, order=9).reason
    assert 'order 2.5 must be an integer' in identify(u, y, period, order=2.5).reason
    assert 'block rows must be an integer >= 2, got 1' in identify(u, y, period, block_rows=1).reason
    assert 'largest order searched must be an integer >= 1' in identify(u, y, period, max_order=0).reason


def test_the_modal_form_gives_back_the_modes_a_model_was_made_of_and_refuses_what_it_cannot_hold():
    """A model held at 1 kHz from known modes (40 Hz, zeta 0.03; 58 Hz, zeta 0.05) and a 20 Hz
    real pole: its modal form is those to 1e-9; two real poles, or a pole outside the unit
    circle, have none (the reason says which)."""
    from machine_ctrl.identification.subspace import StateSpaceModel, modal_form
    from machine_ctrl.model import modal
    modes = [(2 * math.pi * 40.0, 0.03), (2 * math.pi * 58.0, 0.05)]
    a, b, c = modal.state_space(modes, 2 * math.pi * 20.0)
    phi, gamma = modal.held(a, b, 1e-3)
    form = modal_form(StateSpaceModel(phi, gamma[:, None], c[None, :], np.zeros((1, 1)), 1e-3))
    assert form.reason == ''
    np.testing.assert_allclose(np.array(form.modes), np.array(modes), rtol=1e-9)
    assert form.real_pole == pytest.approx(2 * math.pi * 20.0, rel=1e-9)
    two = StateSpaceModel(np.diag([0.9, 0.8]), np.ones((2, 1)), np.ones((1, 2)), np.zeros((1, 1)), 1e-3)
    assert modal_form(two).reason.startswith('2 real poles')
    unstable = StateSpaceModel(np.array([[1.01]]), np.ones((1, 1)), np.ones((1, 1)), np.zeros((1, 1)), 1e-3)
    assert modal_form(unstable).reason.startswith('a pole on or outside the unit circle')
    negative = StateSpaceModel(np.diag([-0.5, 0.9]), np.ones((2, 1)), np.ones((1, 2)), np.zeros((1, 1)), 1e-3)
    assert modal_form(negative).reason == 'a real pole at z < 0: no continuous pole samples to it'
    real = StateSpaceModel(np.array([[0.9]]), np.ones((1, 1)), np.ones((1, 1)), np.zeros((1, 1)), 1e-3)
    assert modal_form(real).reason == 'no pole pair: the modal form needs at least one mode'
