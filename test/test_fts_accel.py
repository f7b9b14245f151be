"""Acceleration feedback on the fts_lathe's W (Ding Ch. 7, seed 003_edeaa855566124b7): the
accelerometer and the cutting-force input of hw_sim, the PID's acceleration loop (Fig. 7-6,
Eq. 7-7), the simulated dynamic compliance against Eq. (7-9) written here from the thesis
alone, and the intermittent cut of section 7.6 (machine_ctrl/experiments/fts_accel.py)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from hw_sim.simulator import MachineSimulator
from machine_ctrl.control.registry import make_law
from machine_ctrl.experiments import fts_accel

M, C, K = 0.074, 2.28, 21965.0            # Ding Table 5-2: m1 + m2, c2, k2
K_T = 3.6658                             # N/A, Ding section 5.5.2
KP, KI, KD, TF = 1.65, 562.0, 9.5e-4, 9.6e-5   # Ding section 7.5.3
S_ACC = 1.0 / 9.80665 / 10.8995          # V per m/s^2: 1000 mV/g (Table 7-2) over 10.8995 (section 7.5.1)


def single_body(machine):
    """fts_lathe with m4 cut loose from m1 (k4, c4 ~ 0): the single body Eq. (7-9) assumes."""
    w = machine.axis('w')
    flexure = dataclasses.replace(w.plant.flexure, secondary_stiffness=1e-9, secondary_damping=0.0)
    axis = dataclasses.replace(w, plant=dataclasses.replace(w.plant, flexure=flexure))
    return dataclasses.replace(machine, axes=tuple(axis if a.name == 'w' else a for a in machine.axes))


def eq_7_9(machine, f, ka):
    """Ding Eq. (7-9) with Table 5-2's single body, Ch. 7 gains, H_I the 400 kHz current loop
    (Eq. 5-9) and H_capa, H_acc second-order low-passes at the machine's sensor and accelerometer
    bandwidths; the DAC -> ADC delay and half a sample are put on H_I."""
    w = machine.axis('w')
    s = 2j * math.pi * np.asarray(f)
    wi, wc, wa = 2 * math.pi * 400e3, w.plant.sensor_bandwidth.omega, 2 * math.pi * 10e3
    h_i = wi ** 2 / (s ** 2 + 2 * 0.707 * wi * s + wi ** 2) * np.exp(-s * (3.5e-6 + 0.5 * machine.control_period))
    s_capa = w.control.pid.sensitivity             # calibrated (fts-budget), not a seed value
    h_capa = s_capa * wc ** 2 / (s ** 2 + 2 * 0.7071 * wc * s + wc ** 2)
    h_acc = S_ACC * wa ** 2 / (s ** 2 + 2 * 0.7071 * wa * s + wa ** 2)
    mass = M + ka * h_acc * h_i * K_T
    damping = C + KD / (TF * s + 1) * h_capa * h_i * K_T
    spring = K + KP * h_capa * h_i * K_T
    return 1.0 / (mass * s ** 2 + damping * s + spring + KI * h_capa * h_i * K_T / s)


@pytest.mark.parametrize('ka', [0.0, 1.0])
def test_simulated_compliance_of_a_single_body_follows_eq_7_9(fts_lathe, ka):
    machine = fts_accel.w_alone(single_body(fts_lathe), ka, scaled=False)
    f = np.array([100.0, 300.0, 1000.0, 2000.0, 5000.0])
    simulated = fts_accel.compliance(machine, f)
    np.testing.assert_allclose(20 * np.log10(simulated), 20 * np.log10(np.abs(eq_7_9(machine, f, ka))), atol=0.5)


def test_the_acceleration_loop_subtracts_k_a_times_the_accelerometer_volts(fts_lathe):
    w = fts_lathe.axis('w')
    gains = dataclasses.replace(w.control.pid, acceleration_gain=2.0)
    law = make_law(dataclasses.replace(w, control=dataclasses.replace(w.control, pid=gains)), fts_lathe.control_period)
    plain = make_law(w, fts_lathe.control_period)
    assert law.uses_acceleration and not plain.uses_acceleration
    for acc, x in ((0.5, 1e-8), (-3.0, 2e-8), (0.0, -1e-8)):
        assert law.step(0.0, 0.0, 0.0, x, 0.0, acc) == pytest.approx(plain.step(0.0, 0.0, 0.0, x, 0.0, acc)
                                                                       - 2.0 * S_ACC * acc, rel=1e-9)


def test_the_shaping_filter_h_a_has_unit_dc_gain_and_its_corner_at_minus_3_db(fts_lathe):
    w, period = fts_lathe.axis('w'), fts_lathe.control_period
    corner = 2 * math.pi * 2000.0
    gains = dataclasses.replace(w.control.pid, proportional=0.0, integral=0.0, derivative=0.0,
                                acceleration_gain=1.0, acceleration_filter=corner)
    law = make_law(dataclasses.replace(w, control=dataclasses.replace(w.control, pid=gains)), period)
    out = [law.step(0.0, 0.0, 0.0, 0.0, 0.0, 1.0) for _ in range(20000)]
    assert -out[-1] / S_ACC == pytest.approx(1.0, rel=1e-9)
    law.reset()
    k = np.arange(40000)
    wave = np.sin(corner * k * period)
    y = np.array([-law.step(0.0, 0.0, 0.0, 0.0, 0.0, a) / S_ACC for a in wave])[20000:]
    amplitude = math.hypot(*np.linalg.lstsq(np.column_stack([np.sin(corner * k[20000:] * period),
                                                             np.cos(corner * k[20000:] * period)]), y, rcond=None)[0])
    assert 20 * math.log10(amplitude) == pytest.approx(-3.01, abs=0.05)       # Tustin warps 2 kHz by 0.1 %


def test_the_acceleration_loop_is_refused_without_an_accelerometer(fts_lathe):
    w = fts_lathe.axis('w')
    bare = dataclasses.replace(w, plant=dataclasses.replace(w.plant, accelerometer=None),
                               control=dataclasses.replace(w.control, pid=dataclasses.replace(
                                   w.control.pid, acceleration_gain=1.0)))
    with pytest.raises(ValueError, match=r'^axis w: acceleration_gain > 0 needs an accelerometer on the axis'):
        make_law(bare, fts_lathe.control_period)
    blind = dataclasses.replace(bare, plant=w.plant, control=dataclasses.replace(w.control, pid=dataclasses.replace(
        w.control.pid, acceleration_gain=1.0, accelerometer_sensitivity=0.0)))
    with pytest.raises(ValueError, match='needs accelerometer_sensitivity > 0'):
        make_law(blind, fts_lathe.control_period)


def test_an_external_force_moves_the_stage_by_its_compliance_and_is_refused_where_there_is_no_input(
        fts_lathe, micromill):
    simulator = MachineSimulator(fts_lathe)
    w = fts_lathe.axis_names.index('w')
    simulator.set_force('w', 0.01)
    for _ in range(200000):                          # 1 s open loop: the flexure settles at F / k2
        simulator.step([0.0] * len(fts_lathe.axes))
    assert simulator.true_position[w] == pytest.approx(0.01 / K, rel=0.02)   # current noise: nm on 455 nm
    assert abs(simulator.measurement.acceleration[w]) < 0.05                  # at rest: noise only, m/s^2
    with pytest.raises(ValueError, match='its plant takes no external force'):
        MachineSimulator(micromill).set_force('x_c', 1.0)
    with pytest.raises(ValueError, match='force must be finite'):
        simulator.set_force('w', math.nan)


@pytest.fixture(scope='module')
def accel_result():
    result = fts_accel.reproduce(frequencies=(100.0, 1000.0, 5000.0))
    assert result['status'] == 'ok', result['reason']
    return result


def test_the_k_g_factors_are_section_7_4_1_s(accel_result, fts_lathe):
    # a design step of the controller: M is its model's (the drive's identified m12, 0.005 %
    # below Table 5-2's)
    m = fts_lathe.axis('w').drive.mass
    assert m == pytest.approx(M, rel=1e-4)
    for ka, kg in accel_result['runs']['kg'].items():
        assert kg == pytest.approx((m + ka * S_ACC * K_T) / m, rel=1e-9)      # the YAML has 11 digits


def test_the_intermittent_cut_peak_falls_with_k_a_to_the_thesis_s_25_nm(accel_result):
    cuts = accel_result['runs']['cuts']
    peaks = [cuts[ka]['peak_following'] for ka in fts_accel.CUT_GAINS]
    assert peaks[0] == pytest.approx(75e-9, rel=0.1)                     # the calibration figure, noise on
    assert all(a > b for a, b in zip(peaks, peaks[1:]))
    assert peaks[-1] == pytest.approx(25e-9, rel=0.3)                    # predicted, section 7.6.2
    for row in accel_result['rows']:
        if row['off']:
            assert len(row['note']) > 40, row


def test_acceleration_feedback_lowers_the_compliance_within_the_sensor_bandwidth(accel_result):
    curves = accel_result['runs']['compliance']
    plain, fed = curves['ka=0'], curves['ka=4 x Kg']
    assert np.all(fed['simulated'] < plain['simulated'])                # 100 Hz, 1 kHz, 5 kHz
    np.testing.assert_allclose(20 * np.log10(fed['simulated']), 20 * np.log10(fed['eq_7_9']), atol=2.0)
