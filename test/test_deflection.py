"""Deflection compensation (Sörnmo thesis, seed 004, Ch. 4): the plant of
hw_sim/robot_compliance.py, the control laws of machine_ctrl/control/deflection.py and the
reproduction of Table 4.1 (machine_ctrl/experiments/deflection.py).

Expected values are written here from the seed and by hand, never computed by the code
under test:

* the process force normal to the feed: 2 flutes x 3 mm x (12.5 um x 767 N/mm^2 / 4 +
  27.7 N/mm / pi) = 67.33 N (feed per tooth 10 mm/s / (2 x 400 rev/s)); at 150 N/mm the
  static deflection is 448.9 um;
* C(s) = k_c w_c / (s + w_c), w_c = 2 pi 0.9 rad/s, k_c = w_c / 4 = 1.41372 1/s;
* a type-1 loop (the integrated velocity reference) driven to a new level d integrates
  its error to d / k_c; following a ramp of slope r it lags by r / k_c.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from experiment_cli import experiment_json
from hw_sim.robot_compliance import MillingConfig, MillingRobot, RobotConfig
from machine_ctrl.control import deflection as law
from machine_ctrl.control.deflection import DeflectionConfig, StiffnessTable, Status, design
from machine_ctrl.experiments import deflection as experiment

FORCE = 2 * 3e-3 * (12.5e-6 * 767e6 / 4 + 27.7e3 / math.pi)      # N, hand (module doc)
K0 = 150e3                                                       # N/m, the plant's nominal stiffness
DEFLECTION = FORCE / K0                                          # m
WC = 2 * math.pi * 0.9                                           # rad/s, 9 Hz / 10
KC = WC / 4                                                      # 1/s
H = 1 / 250                                                      # s, ORCA

# the plant without the stiffness variation and the non-force offset, no ripple, no tooth-to-tooth variation: the
# controller's table can then be exact, and what is left is the physics under test
PLAIN = RobotConfig(stiffness_variation=0.0, offset=0.0)
STEADY = MillingConfig(ripple=0.0, variation=0.0)
EXACT = StiffnessTable((-1.0, 1.0), (K0, K0))
CHOICES = experiment.Choices()


def _run(mode, robot=PLAIN, milling=STEADY, choices=CHOICES):
    result = design(DeflectionConfig(), EXACT)
    assert result.ok, result.reason
    return experiment.simulate(mode, robot, milling, result.design, choices, record=True)['signals']


def _middle(signals, seconds=1.0):
    """The samples of `seconds` around the middle of the cut (the loop settled)."""
    t, cut = signals['time'], signals['cutting']
    mid = 0.5 * (t[cut][0] + t[cut][-1])
    return np.abs(t - mid) <= seconds / 2


# --- the plant ----------------------------------------------------------------------------

def test_force_and_static_deflection_by_hand():
    assert STEADY.removal * STEADY.feed == pytest.approx(FORCE, rel=1e-9)
    s = _run('none')
    mid = _middle(s)
    assert np.mean(s['force'][mid]) == pytest.approx(FORCE, rel=0.01)       # JR3 noise 0.09 N per period
    assert np.mean(s['arm'][mid]) == pytest.approx(DEFLECTION, rel=0.005)   # Eq. (4.1): f = k x_p


def test_structural_mode_rings_at_9_hz():
    plant = MillingRobot(PLAIN, STEADY, seed=0, lead_in=2.0)
    plant.deflection = 1e-4                   # released from a deflection, no force before contact
    z = []
    for _ in range(int(1.8 / H)):
        z.append(plant.arm_position())
        plant.step(0.0, 0.0)
    z = np.array(z)
    assert plant.motor_position() == 0.0      # the motor side does not see the arm's deflection
    up = np.nonzero((z[:-1] < 0) & (z[1:] >= 0))[0]
    crossings = (up + z[up] / (z[up] - z[up + 1])) * H       # linear interpolation
    frequency = (len(crossings) - 1) / (crossings[-1] - crossings[0])
    assert frequency == pytest.approx(9.0 * math.sqrt(1 - 0.05 ** 2), rel=0.005)


def test_load_test_measures_the_stiffness():
    plant = MillingRobot(RobotConfig(), STEADY, seed=3)
    measured = plant.measure_stiffness([0.0, 0.025, 0.075], load=100.0, readings=250)
    # k(x) = 150 + 5 sin(2 pi x / 100 mm) N/mm: 150, 155, 145 N/mm
    assert measured == pytest.approx([150e3, 155e3, 145e3], rel=0.01)


# --- the control laws ---------------------------------------------------------------------

def test_stiffness_table_interpolates_linearly_and_holds_its_ends():
    table = StiffnessTable((0.0, 0.02, 0.04), (140e3, 150e3, 145e3))
    assert table.at(0.005) == pytest.approx(142.5e3)
    assert table.at(0.03) == pytest.approx(147.5e3)
    assert table.at(0.02) == pytest.approx(150e3)
    assert table.at(-1.0) == pytest.approx(140e3)
    assert table.at(1.0) == pytest.approx(145e3)


def test_error_signals():
    # FF: 67.33 N on 150 N/mm deflects +448.9 um: with z_m = 0 the arm is estimated there
    assert law.force_feedback_error(0.0, 0.0, FORCE, K0) == pytest.approx(-DEFLECTION)
    # ... and once the robot has moved back by the deflection, nothing is left to correct
    assert law.force_feedback_error(0.0, -DEFLECTION, FORCE, K0) == pytest.approx(0.0, abs=1e-15)
    assert law.position_feedback_error(1e-3, 0.7e-3) == pytest.approx(0.3e-3)


def test_controller_defaults_follow_the_seed():
    c = DeflectionConfig()
    assert c.period == pytest.approx(0.004)            # ORCA 250 Hz, §4.3
    assert c.cutoff == pytest.approx(0.9)              # a decade below 9 Hz (§2.6)
    assert c.gain == pytest.approx(1.41372, rel=1e-5)  # w_c / 4


@pytest.mark.parametrize('f', [0.0, 0.05, 0.3, 0.9, 2.0, 5.0])
def test_low_pass_matches_the_continuous_controller(f):
    section = design().design.low_pass()
    z = np.exp(1j * 2 * math.pi * f * H)
    discrete = (section.b0 + section.b1 / z + section.b2 / z ** 2) / (1 + section.a1 / z + section.a2 / z ** 2)
    continuous = KC * WC / (1j * 2 * math.pi * f + WC)
    if f in (0.0, 0.9):                              # DC and the pre-warped cut-off: exact
        assert abs(discrete) == pytest.approx(abs(continuous), rel=1e-9)
    else:                                            # Tustin's warping, far below Nyquist (125 Hz)
        assert discrete == pytest.approx(continuous, rel=2e-3)
    if f == 0.9:
        assert abs(discrete) == pytest.approx(KC / math.sqrt(2), rel=1e-9)


def test_compensator_integrates_the_velocity_reference():
    comp = law.DeflectionCompensator(design().design)
    for _ in range(5000):                            # 20 s, far past the 0.18 s low-pass
        velocity, correction = comp.step(1e-4)
    assert velocity == pytest.approx(KC * 1e-4, rel=1e-9)
    # backward Euler of the low-pass's step response: k_c e (t - 1/w_c) at t = 20 s
    assert correction == pytest.approx(KC * 1e-4 * (20 - 1 / WC), rel=2e-3)


@pytest.mark.parametrize('config, table, words', [
    (DeflectionConfig(gain=0.0), None, 'gain must be positive'),
    (DeflectionConfig(gain=-1.0), None, 'gain must be positive'),
    (DeflectionConfig(gain=float('nan')), None, 'finite'),
    (DeflectionConfig(cutoff=130.0), None, 'Nyquist'),
    (DeflectionConfig(cutoff=0.0), None, 'Nyquist'),
    (DeflectionConfig(period=0.0), None, 'period must be positive'),
    (DeflectionConfig(gain='fast'), None, 'must be numbers'),
    (DeflectionConfig(), StiffnessTable((0.0, 0.02, 0.01), (1e5, 1e5, 1e5)), 'strictly increasing'),
    (DeflectionConfig(), StiffnessTable((0.0, 0.0), (1e5, 1e5)), 'strictly increasing'),
    (DeflectionConfig(), StiffnessTable((0.0, 0.02), (1e5, 0.0)), 'must be positive'),
    (DeflectionConfig(), StiffnessTable((0.0, 0.02), (1e5, -1e5)), 'must be positive'),
    (DeflectionConfig(), StiffnessTable((0.0, float('nan')), (1e5, 1e5)), 'finite'),
    (DeflectionConfig(), StiffnessTable((0.0, 0.02), (1e5,)), 'one stiffness per position'),
    (DeflectionConfig(), StiffnessTable((0.0,), (1e5,)), 'at least two points'),
])
def test_bad_designs_are_refused_with_a_reason(config, table, words):
    result = design(config, table)
    assert result.status is Status.FAILED and not result.ok
    assert result.design is None
    assert words in result.reason


# --- the closed loops ---------------------------------------------------------------------

def test_force_feedback_removes_the_static_deflection():
    s = _run('ff')
    mid = _middle(s)
    assert np.max(np.abs(s['arm'][mid])) < 3e-6                       # from 448.9 um
    assert np.mean(s['correction'][mid]) == pytest.approx(-DEFLECTION, rel=0.01)
    # on entry the type-1 loop integrates its error to the deflection / k_c (module doc)
    entry = s['cutting'] & (s['time'] <= s['time'][mid][0])
    assert np.sum(s['arm'][entry]) * H == pytest.approx(DEFLECTION / KC, rel=0.03)


def test_calibration_drift_pf_removes_it_ff_does_not():
    drift = 1e-3                                                       # m per m of feed
    robot = dataclasses.replace(PLAIN, drift=drift)
    ff, pf = _run('ff', robot), _run('pf', robot)
    mid = _middle(ff)
    x = -3e-3 + 0.01 * (ff['time'][mid] - CHOICES.lead_in)             # tool centre, m
    # FF removes the force's deflection but sees nothing of the drift
    assert ff['arm'][mid] == pytest.approx(drift * x, abs=3e-6)
    # PF follows the drift's ramp (1e-5 m/s) with the type-1 lag r / k_c = 7.07 um
    assert np.mean(pf['arm'][mid]) == pytest.approx(drift * 0.01 / KC, abs=1.5e-6)


# --- Table 4.1 ------------------------------------------------------------------------------

@pytest.fixture(scope='module')
def table():
    return experiment.reproduce()


def test_reproduce_is_bit_for_bit_repeatable(table):
    assert table['status'] == 'ok', table['reason']
    again = experiment.reproduce()
    assert again['rows'] == table['rows']
    assert again['iae_tracker_um'] == table['iae_tracker_um']


def test_the_seed_is_used():
    result = design(DeflectionConfig(), EXACT)
    runs = [experiment.simulate('pf', RobotConfig(), MillingConfig(), result.design,
                                experiment.Choices(seed=seed))['iae'] for seed in (0, 1)]
    assert runs[0] != runs[1]


def test_table_rows_and_compensation(table):
    rows = {row['name']: row for row in table['rows']}
    assert len(rows) == 6
    assert all(row['seed'] in (218.7, 36.3, 6.0, 246.5, 27.2, 9.1) for row in rows.values())
    none = rows['FF IAE uncompensated (shared run)']['ours']
    # the uncompensated pass is about the static deflection (+40 um offset, minus the ramps)
    assert 350 < none < 550
    for label in ('FF', 'PF'):
        assert rows[f'{label} IAE compensated']['ours'] < none / 4
        assert rows[f'{label} IAE ratio']['ours'] > 4
    assert all(row['note'] for row in rows.values() if row['off'])
    # PF also removes the non-force offset, FF cannot (Fig. 4.6 vs 4.7)
    assert rows['PF IAE compensated']['ours'] < rows['FF IAE compensated']['ours']
    assert table['fig_4_8_iae_um']['pf'] < table['fig_4_8_iae_um']['ff'] / 2


def test_format_table_prints_seed_ours_and_assumptions(table):
    text = experiment.format_table(table)
    assert '218.7' in text and '9.1' in text and 'assumed:' in text
    assert experiment.format_table({'status': 'failed', 'reason': 'why'}).endswith('why')


def test_the_command_prints_table_4_1_and_writes_the_plot(tmp_path):
    """`machine-ctrl experiment deflection --json --plots DIR`: the CLI wiring."""
    data = experiment_json('deflection', tmp_path)
    assert [row['seed'] for row in data['rows']] == [218.7, 36.3, 6.0, 246.5, 27.2, 9.1]
    assert [p.name for p in tmp_path.iterdir()] == ['deflection_table_4_1.png']
