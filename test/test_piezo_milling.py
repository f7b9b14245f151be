"""Sörnmo's piezo micro manipulator (seed 004, Ch. 2; issue [4/8]): the axis model of
hw_sim/piezo_stage.py, the realizations the LQG is designed in (identification/subspace.py:
balanced, re-sampled) and the experiment of machine_ctrl/experiments/piezo_milling.py, each
checked against what is known without the code under test: the continuous transfer function,
scipy's zero-order-hold discretization, the Gramians' definition."""
import math

import numpy as np
import pytest
from scipy import signal
from scipy.linalg import solve_discrete_lyapunov

from experiment_cli import experiment_json
from hw_sim.piezo_stage import PiezoAxis, PiezoAxisModel
from machine_ctrl.experiments import piezo_milling
from machine_ctrl.identification.subspace import (NoiseCovariance, StateSpaceModel, balanced, identify,
                                                  resampled)

Y = piezo_milling.AXES['y']         # one mode at 47 Hz, zeta 0.04


def sampled(num, den, period):
    a, b, c, d, _ = signal.cont2discrete(signal.tf2ss(num, den), period, method='zoh')
    return StateSpaceModel(a, b, c, d, period)


def response(model: StateSpaceModel, frequency: float) -> complex:
    z = np.exp(2j * math.pi * frequency * model.period)
    return complex((model.c @ np.linalg.solve(z * np.eye(model.order) - model.a, model.b) + model.d)[0, 0])


NOISE2 = NoiseCovariance(np.eye(2) * 1e-4, np.array([[1e-2]]), np.ones((2, 1)) * 1e-3)


def test_a_model_resampled_is_the_same_continuous_system_held_at_the_new_period():
    w = 2 * math.pi * 47.0
    num, den = [w * w], [1.0, 2 * 0.04 * w, w * w]
    slow, fast = sampled(num, den, 1 / 167.0), sampled(num, den, 1e-4)
    ours, noise = resampled(slow, NOISE2, 1e-4)
    assert ours.period == 1e-4
    assert np.sort_complex(ours.poles()) == pytest.approx(np.sort_complex(fast.poles()), rel=1e-9)
    for f in (0.0, 10.0, 47.0, 300.0):
        assert response(ours, f) == pytest.approx(response(fast, f), rel=1e-8)
    ratio = 1e-4 * 167.0            # densities: process x ratio, measurement / ratio
    assert noise.process == pytest.approx(NOISE2.process * ratio)
    assert noise.measurement == pytest.approx(NOISE2.measurement / ratio)
    negative = StateSpaceModel(np.array([[-0.5]]), np.array([[1.0]]), np.array([[1.0]]), np.zeros((1, 1)), 0.01)
    with pytest.raises(ValueError, match='negative real axis'):
        resampled(negative, NoiseCovariance(np.eye(1), np.eye(1), np.zeros((1, 1))), 1e-3)


def test_the_balanced_realization_has_equal_diagonal_gramians_and_the_same_response():
    w = 2 * math.pi * 47.0
    model = sampled([w * w], [1.0, 2 * 0.04 * w, w * w], 1 / 167.0)
    ours, noise = balanced(model, NOISE2)
    reach = solve_discrete_lyapunov(ours.a, ours.b @ ours.b.T)
    observe = solve_discrete_lyapunov(ours.a.T, ours.c.T @ ours.c)
    assert reach == pytest.approx(observe, rel=1e-8, abs=1e-10)
    assert reach - np.diag(np.diag(reach)) == pytest.approx(np.zeros((2, 2)), abs=1e-9 * reach.max())
    for f in (0.0, 20.0, 47.0, 80.0):
        assert response(ours, f) == pytest.approx(response(model, f), rel=1e-9)
    assert noise.measurement == NOISE2.measurement
    for f in (5.0, 47.0):                       # what the noise does at the output: basis-free
        z = np.exp(2j * math.pi * f * model.period)
        seen = [m.c @ np.linalg.inv(z * np.eye(2) - m.a) for m in (model, ours)]
        assert seen[1] @ noise.process @ seen[1].conj().T == pytest.approx(
            seen[0] @ NOISE2.process @ seen[0].conj().T, rel=1e-9)
        assert seen[1] @ noise.cross == pytest.approx(seen[0] @ NOISE2.cross, rel=1e-9)
    unreachable = StateSpaceModel(np.diag([0.5, 0.3]), np.array([[1.0], [0.0]]), np.array([[1.0, 1.0]]),
                                  np.zeros((1, 1)), 0.01)
    with pytest.raises(ValueError, match='not minimal'):
        balanced(unreachable, NOISE2)


def test_the_axis_has_unit_static_gain_its_resonance_and_a_counted_stroke():
    period = 1e-4
    axis = PiezoAxis(Y, period, np.random.default_rng(0))
    for _ in range(int(2.0 / period)):                  # 2 s: 70 time constants of the 47 Hz mode
        axis.step(10e-6)
    assert axis.position == pytest.approx(10e-6, rel=1e-6)
    axis = PiezoAxis(Y, period, np.random.default_rng(0))
    t = np.arange(int(3.0 / period)) * period
    out = []
    for tk in t:                                        # driven at the mode: gain 1 / (2 zeta) = 12.5
        out.append(axis.position)
        axis.step(1e-6 * math.sin(2 * math.pi * 47.0 * tk))
    assert max(np.abs(out[len(out) // 2:])) / 1e-6 == pytest.approx(1 / (2 * 0.04), rel=0.02)
    assert axis.saturated == 0
    axis.step(2 * Y.stroke)
    axis.step(-Y.stroke)                                # at the stroke: not past it
    assert axis.saturated == 1
    with pytest.raises(ValueError, match=r'mode 47.0 Hz, zeta 1.5: needs f > 0 and 0 < zeta < 1.*stroke'):
        PiezoAxisModel(((47.0, 1.5),), None, 0.0, 1e-9)


def test_each_axis_is_identified_with_its_order_and_first_eigenfrequency():
    for name, model in piezo_milling.AXES.items():
        u, y, period = piezo_milling.chirp_record(model, np.random.default_rng(3))
        assert period == pytest.approx(0.006)
        result = identify(u, y, period)
        assert result.ok, result.reason
        assert result.model.order == model.order == piezo_milling.SEED_ORDER[name]
        assert piezo_milling.first_eigenfrequency(result.model) == pytest.approx(model.modes[0][0], rel=0.01)


def test_the_lqg_at_10_khz_follows_a_step_on_the_true_axis_and_its_integral_removes_the_static_error():
    """l_r gives the identified model unit static gain; what the model misses, the integral
    state removes, slowly: Q = I weighs it per 0.1 ms sample (its time constant here is ~2 s)."""
    law = piezo_milling.controller('y', Y, np.random.default_rng(5))['law']
    axis = PiezoAxis(Y, piezo_milling.PERIOD, np.random.default_rng(6))
    out = []
    for _ in range(int(8.0 / piezo_milling.PERIOD)):
        out.append(axis.position)
        axis.step(law.step(10e-6, axis.measure()))
    error = np.abs(np.array(out) / 10e-6 - 1.0)
    at = [error[int(t / piezo_milling.PERIOD) - 1] for t in (0.5, 2.0, 8.0)]
    assert at[0] < 0.05 and at[2] < at[1] < at[0] and at[2] < 0.002, at
    assert max(out) / 10e-6 < 1.5                          # the 47 Hz mode damped (open loop: 2x)


def test_a_milling_run_repeats_bit_for_bit():
    d, machined = piezo_milling.deviation(piezo_milling.SEED_NUMBER)
    d, machined = d[:15000], machined[:15000]               # the first 1.5 s: at rest, the entry, the cut
    first, second = (piezo_milling.mill('y', Y, d, machined) for _ in range(2))
    assert np.array_equal(first.pop('error'), second.pop('error')) and first == second


def test_the_command_compensates_every_axis_better_than_none_and_writes_the_plot(tmp_path):
    """`machine-ctrl experiment piezo-milling --json --plots DIR`: the seed's figures written
    here (Tables 2.1 / 2.2, section 2.3), ours below the uncompensated on every axis."""
    data = experiment_json('piezo-milling', tmp_path)
    seeds = {row['name']: row['seed'] for row in data['rows']}
    assert [seeds[f'{a}: e_m compensated'] for a in 'xyz'] == [14.0, 12.8, 24.5]
    assert [seeds[f'{a}: sigma_e uncompensated'] for a in 'xyz'] == [7.6, 5.6, 14.9]
    assert [seeds[f'{a}: VAF % (2.3)'] for a in 'xyz'] == [92.5, 99.5, 97.1]
    assert set(data['axes']) == {'x', 'y', 'z'}
    for name, axis in data['axes'].items():
        assert axis['order'] == {'x': 4, 'y': 2, 'z': 5}[name]
        for key in ('e_m', 'sigma_e'):
            assert axis['compensated'][key] < axis['uncompensated'][key], (name, key, axis)
    assert [p.name for p in tmp_path.iterdir()] == ['piezo_milling.png']
