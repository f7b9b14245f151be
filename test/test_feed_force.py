"""Sörnmo Ch. 5's adaptive feed-rate force control (hw_sim/feed_process.py,
machine_ctrl/control/feed_force.py, machine_ctrl/experiments/feed_force.py): the process
against Eq. (5.4)'s static force, the D_f estimator against data of the exact discrete model,
the LQ design's loop, the controller holding the force, and the command."""
import math

import numpy as np
import pytest

from experiment_cli import experiment_json
from hw_sim.feed_process import FeedProcess, RemovalProfile
from hw_sim.robot_compliance import RobotConfig
from machine_ctrl.control.feed_force import (AdaptationConfig, ControllerState, FeedForceController,
                                             RemovalEstimator, design, force_model)

H = 1.0 / 250.0          # ORCA's period, Sörnmo §5.4


@pytest.fixture(scope='module')
def identified():
    from machine_ctrl.experiments.feed_force import identify_robot
    result = identify_robot(RobotConfig())
    assert result.ok, result.reason
    return result


def test_removal_profile_steps_ramps_and_refusals():
    profile = RemovalProfile(((0.0, 3e3), (8.0, 3e3), (8.0, 6e3), (10.0, 6e3), (12.0, 2e3)))
    assert [profile.at(t) for t in (-1.0, 7.99, 8.0, 9.0, 11.0, 12.0, 99.0)] == [3e3, 3e3, 6e3, 6e3, 4e3, 2e3, 2e3]
    for points, reason in ((((1.0, 2e3), (0.5, 2e3)), 'must not decrease'), (((0.0, 0.0),), 'positive'),
                           (((0.0, math.nan),), 'positive'), ((), 'at least one')):
        with pytest.raises(ValueError, match=reason):
            RemovalProfile(points)


def test_the_process_force_settles_to_d_f_times_the_feed():
    """Eq. (5.4): at a constant feed v in a constant material the force settles to D_f v,
    with the time constant D_f / K_f; in the air the JR3 reads its noise only."""
    removal, stiffness, feed = 4e3, 50e3, 5e-3
    plant = FeedProcess(RobotConfig(force_noise=0.0), stiffness, RemovalProfile(((0.0, removal),)), seed=1,
                        velocity_noise=0.0)
    for _ in range(500):                          # 2 s: 25 time constants of 0.08 s, the servo settled
        plant.step(feed)
    assert plant.true_force() == pytest.approx(removal * feed, rel=1e-6)
    assert plant.force_reading() == plant.true_force() and plant.velocity_reading() == pytest.approx(feed, rel=1e-9)
    air = FeedProcess(RobotConfig(), stiffness, None, seed=1)
    readings = []
    for _ in range(400):
        air.step(feed)
        readings.append(air.force_reading())
    assert air.true_force() == 0.0 and math.isnan(air.removal_now())
    # the JR3's noise averaged over a period's 32 samples: 0.5 / sqrt(32) N RMS
    assert np.std(readings) == pytest.approx(0.5 / math.sqrt(32), rel=0.15)


def test_the_estimator_recovers_d_f_from_the_exact_discrete_model():
    """Data made here from f_k+1 = a f_k + (1 - a) D_f v_k (a = exp(-K_f h / D_f)), a feed
    that varies and then holds, a step of D_f: the estimate is D_f to 1e-6 before and after."""
    stiffness = 85e3
    estimator = RemovalEstimator(H, stiffness, initial=1e3, forgetting=0.99)
    rng = np.random.default_rng(3)
    force = 0.0
    for removal in (2.5e3, 5e3):
        a = math.exp(-stiffness * H / removal)
        for k in range(1500):
            v = 6e-3 + (2e-3 * rng.standard_normal() if k < 700 else 0.0)
            nxt = a * force + (1.0 - a) * removal * v
            estimator.update(force, v, nxt)
            force = nxt
        assert estimator.value == pytest.approx(removal, rel=1e-6)
    assert estimator.spread < 1e-3          # far below the 2 % that activates the controller


def test_the_force_row_has_eq_5_9s_pole_and_static_gain():
    """The augmented model of a known G_v (one pole at 0.6, static gain 2, a direct term):
    the force state's pole is exp(-K_f h / D_f) and, at rest under a constant v_r, the force
    is D_f times the velocity G_v gives (Eq. 5.4's static gain)."""
    from machine_ctrl.identification.subspace import StateSpaceModel
    g = StateSpaceModel(np.array([[0.6]]), np.array([[0.5]]), np.array([[1.2]]), np.array([[0.5]]), H)
    stiffness, removal, u = 50e3, 3e3, 4e-3
    a, b = force_model(g, stiffness, removal)
    assert a[0, 1] == 0.0 and a[1, 1] == pytest.approx(math.exp(-stiffness * H / removal), rel=1e-12)
    rest = np.linalg.solve(np.eye(2) - a, b * u)
    velocity = (1.2 * 0.5 / (1 - 0.6) + 0.5) * u               # C (1 - A)^-1 B + D = 2, times v_r
    assert rest[1] == pytest.approx(removal * velocity, rel=1e-12)


def test_the_lq_loop_is_stable_over_two_decades_of_d_f_and_a_bad_one_is_refused(identified):
    model = identified.model
    n = model.order
    for removal in (0.3e3, 1e3, 3e3, 10e3, 30e3):
        result = design(model, 50e3, removal)
        assert result.ok, result.reason
        g = result.design
        a, b = force_model(model, 50e3, removal)
        closed = np.zeros((n + 2, n + 2))      # [x, x_f, x_i] under v_r = -L [x, x_f] - l_i x_i
        closed[:n + 1, :n + 1] = a - np.outer(b, g.feedback)
        closed[:n + 1, n + 1] = -b * g.integral_gain
        closed[n + 1, n], closed[n + 1, n + 1] = -H, 1.0
        assert np.abs(np.linalg.eigvals(closed)).max() < 1.0, removal
    refused = design(model, 50e3, -1.0)
    assert not refused.ok and refused.reason == 'K_f and D_f must be positive, got 50000.0 N/m and -1.0 N s/m'


def test_the_controller_holds_the_force_and_starts_without_a_bump(identified):
    """Activation once D_f is known, v_r continuous there, the force at its reference after a
    step of D_f; the same seed gives the same run to the bit."""
    def run():
        config = AdaptationConfig(initial_feed=6e-3)
        controller = FeedForceController(identified.model, identified.noise, 50e3, config)
        plant = FeedProcess(RobotConfig(), 50e3, RemovalProfile(((0.0, 3e3), (4.0, 3e3), (4.0, 6e3))), seed=7)
        inputs, forces, states = [], [], []
        for _ in range(2500):                     # 10 s
            u = controller.step(plant.force_reading(), plant.velocity_reading(), 20.0)
            plant.step(u)
            inputs.append(u), forces.append(plant.true_force()), states.append(controller.state)
        return controller, np.array(inputs), np.array(forces), states
    controller, u, f, states = run()
    start = states.index(ControllerState.ACTIVE)
    assert 0 < start < 250 and controller.activated_at == start
    assert abs(u[start] - 6e-3) < 1e-4                       # bumpless: the constant feed goes on
    assert np.mean(f[-250:]) == pytest.approx(20.0, abs=0.05)           # the last second, D_f doubled
    assert np.mean(u[-250:]) == pytest.approx(20.0 / 6e3, rel=0.02)     # at the feed D_f v = f_r asks
    assert controller.estimator.value == pytest.approx(6e3, rel=0.02) and controller.designs > 1
    again = run()
    assert np.array_equal(again[1], u) and np.array_equal(again[2], f)


def test_the_command_prints_the_runs_and_writes_the_figure(tmp_path):
    data = experiment_json('feed-force', tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['feed_force.png']
    assert data['identified']['vaf_percent'] > 95.0 and data['identified']['seed_order'] == 3
    for key in ('adaptive', 'fixed', 'aluminium'):
        run = data['runs'][key]
        assert run['activated_s'] < 2.0 and run['rms_error_n'] < 0.05 * (50.0 if key == 'aluminium' else 20.0)
    adaptive = data['runs']['adaptive']
    assert all(math.isfinite(e['settle_s']) for e in adaptive['events'].values())
    assert set(data['slower_loops']) == {'10.0', '100.0'}
