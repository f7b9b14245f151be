"""Identification of a feed drive (issue [8/8] part 1, begun: machine_ctrl/identification/
rigid_body.py, machine_ctrl/experiments/identify.py, `machine-ctrl identify`): the fits on
synthetic data of known parameters, the whole identification of the micromill's x_c on hw_sim
against the simulator's true values (fixed seed), the YAML fragment loading as a machine
config, and the refusals."""
import json
import math

import numpy as np
import pytest
import yaml

from machine_ctrl.identification.rigid_body import fit_rigid_body, fit_steady_friction, lowpass
from machine_ctrl.identification.status import FitStatus
from machine_ctrl.model.config import load_machine

PERIOD = 1e-4


def synthetic(seconds=8.0, noise=0.5, seed=3):
    """A multisine over a slow sweep (x, v, a analytic) and the force of m = 20 kg, b = 30 N s/m,
    F_c = (40, 25) N varying by 10 % along a 30 mm wavelength, with white noise."""
    t = np.arange(int(seconds / PERIOD)) * PERIOD
    tones = [(0.7, 4e-3), (1.9, 2e-3), (4.1, 1e-3)]
    x = 0.02 * np.sin(2 * math.pi * 0.25 * t) + sum(amp * np.sin(2 * math.pi * f * t + f) for f, amp in tones)
    v = 0.02 * 2 * math.pi * 0.25 * np.cos(2 * math.pi * 0.25 * t) + sum(
        amp * 2 * math.pi * f * np.cos(2 * math.pi * f * t + f) for f, amp in tones)
    a = -0.02 * (2 * math.pi * 0.25) ** 2 * np.sin(2 * math.pi * 0.25 * t) - sum(
        amp * (2 * math.pi * f) ** 2 * np.sin(2 * math.pi * f * t + f) for f, amp in tones)
    scale = 1.0 + 0.1 * np.sin(2 * math.pi * x / 0.03)
    force = 20.0 * a + 30.0 * v + scale * np.where(v > 0, 40.0, -25.0)
    return force + np.random.default_rng(seed).normal(0.0, noise, len(t)), x


def test_the_rigid_body_fit_finds_known_parameters_with_narrow_intervals():
    """Within 3 % of the parameters the data was made with (measured < 0.6 %), each interval
    under 5 % wide. The intervals do not all hold the true value (b: 30.09 +- 0.02): the residual
    of filtered data is not white, as rigid_body.py says."""
    force, x = synthetic()
    fit = fit_rigid_body(force, x, PERIOD, 5e-3, np.geomspace(5e-3, 0.1, 61))
    assert fit.status is FitStatus.OK, fit.reason
    for estimate, true in ((fit.mass, 20.0), (fit.viscous, 30.0), (fit.coulomb[0], 40.0), (fit.coulomb[1], 25.0)):
        assert estimate.within(true, 0.03), (estimate, true)
        assert 0 < estimate.half_width < 0.05 * true
    assert fit.variation.wavelength == pytest.approx(0.03, rel=0.03)
    assert fit.variation.amplitude == pytest.approx((0.1, 0.1), rel=0.1)


def test_the_steady_friction_fit_finds_the_stribeck_curve_and_b():
    speeds = np.geomspace(5e-5, 0.1, 10)
    curves = ((36.0, 40.0, 1.3e-3, 1.8e-3), (29.0, 27.0, 0.34e-3, 0.45e-3))
    forces = np.array([[fs * math.exp(-v / w1) + fc * (1 - math.exp(-v / w2)) + 25.0 * v for v in speeds]
                       for fs, fc, w1, w2 in curves])           # Eq. (4.41), written out here
    fit = fit_steady_friction(np.tile(speeds, (2, 1)), forces)
    assert fit.status is FitStatus.OK, fit.reason
    assert fit.viscous == pytest.approx(25.0, rel=1e-3)
    for found, true in zip(fit.curves, curves):
        assert (found.static, found.coulomb, found.omega1, found.omega2) == pytest.approx(true, rel=1e-3)


@pytest.mark.parametrize('force, position, reason', [
    (np.zeros(500), np.zeros(500), '500 samples: at least 1000 needed'),
    (np.zeros(2000), np.zeros(1999), 'must be equally long'),
    (np.full(2000, np.nan), np.zeros(2000), 'NaN or inf'),
    (np.zeros(20000), np.linspace(0.0, 0.01, 20000), 'not both directions'),     # one way only
])
def test_data_that_cannot_give_a_rigid_body_is_refused_with_the_reason(force, position, reason):
    fit = fit_rigid_body(force, position, PERIOD, 5e-3)
    assert fit.status is FitStatus.REFUSED and reason in fit.reason, fit.reason


def test_steady_friction_data_that_cannot_give_a_curve_is_refused_with_the_reason():
    speeds = np.tile(np.geomspace(1e-4, 0.1, 6), (2, 1))
    assert 'at least 5 needed' in fit_steady_friction(speeds[:, :4], np.ones((2, 4))).reason
    assert 'finite and > 0' in fit_steady_friction(speeds, -np.ones((2, 6))).reason
    assert 'two decades' in fit_steady_friction(np.tile(np.linspace(0.01, 0.1, 6), (2, 1)), np.ones((2, 6))).reason
    assert 'must be (2, n) arrays' in fit_steady_friction(speeds[0], np.ones(6)).reason


def test_the_filter_is_zero_phase():
    t = np.arange(20000) * PERIOD
    slow = np.sin(2 * math.pi * 2.0 * t)
    assert np.abs(lowpass(slow, PERIOD) - slow)[2000:-2000].max() < 1e-6


@pytest.fixture(scope='module')
def y_c(micromill):
    from machine_ctrl.experiments.identify import identify
    return identify(micromill, 'y_c', workers=1)


@pytest.fixture(scope='module')
def x_c(micromill):
    from machine_ctrl.experiments.identify import identify
    return identify(micromill, 'x_c', workers=1)


def test_x_c_of_the_simulated_micromill_is_identified_near_what_hw_sim_simulates(x_c):
    """Against the simulator's true values (the machine config's plant section: the mass is
    the controllers' Table 4.1 m^ plus a workpiece, README "Truth and belief"),
    seed 1: mass and b within 3 % (measured 1.3 %, 1.6 %), the static and Coulomb levels within
    10 % as the issue asks (measured < 0.5 %), the Stribeck velocities and the variation along
    the stroke within 10 % (measured < 1.5 %)."""
    assert x_c['status'] == 'ok', x_c['reason']
    true, body, steady = x_c['true'], x_c['rigid_body'], x_c['steady']
    assert body.mass.within(true['mass'], 0.03)
    assert steady.viscous == pytest.approx(true['viscous'], rel=0.03)
    for d, curve in enumerate(steady.curves):
        for name in ('static', 'coulomb', 'omega1', 'omega2'):
            assert getattr(curve, name) == pytest.approx(true[name][d], rel=0.10), (name, d)
    assert body.variation.wavelength == pytest.approx(true['variation_wavelength'], rel=0.05)
    assert body.variation.amplitude == pytest.approx((true['variation'],) * 2, rel=0.10)


@pytest.mark.parametrize('axis', ['x_c', 'y_c'])
def test_the_bristles_from_presliding_steps_are_within_10_percent_of_the_plants(axis, x_c, y_c):
    """LuGre's sigma0, sigma1 from two open-loop force steps of half the static level, the
    model's m, b and friction curve the identified ones: within 10 % of what hw_sim simulates
    (measured +1.0 / +0.2 % on x_c, +1.0 / +0.1 % on y_c)."""
    result = {'x_c': x_c, 'y_c': y_c}[axis]
    bristles, true = result['bristles'], result['true']
    assert bristles.sigma0 == pytest.approx(true['sigma0'], rel=0.10)
    assert bristles.sigma1 == pytest.approx(true['sigma1'], rel=0.10)


def test_the_closed_loop_frf_is_coherent_at_its_bandwidth_and_meets_the_stepped_sines(micromill, x_c):
    """The noise-excited FRF of x_c's loop (identify.closed_loop_frf): a gain of 1 within 0.5 dB
    and a coherence above 0.99 at 2 Hz, the -3 dB point reported with a coherence of 0.9 or
    more (measured 0.94), and within 10 % of the -3 dB point of `experiment frf`'s stepped sine
    (tracking.frequency_response: a lock-in at each frequency, another method and another
    excitation) read at 20-60 Hz (measured 37.0 against 34.6 Hz: the axis is not linear, its
    friction and presliding answer a sine of 50 um and a broadband 35 um rms differently)."""
    from machine_ctrl.experiments import tracking
    frf = x_c['frf']
    low = int(np.argmin(np.abs(frf['frequencies_hz'] - 2.0)))
    assert abs(20 * math.log10(frf['gain'][low])) < 0.5 and frf['coherence'][low] > 0.99
    assert frf['bandwidth_hz'] is not None and frf['coherence_at_bandwidth'] >= 0.9
    band = frf['coherent_band_hz']
    assert band[0] < 2.0 and band[1] > 0.8 * frf['bandwidth_hz']
    lines = np.geomspace(20.0, 60.0, 7)
    channel = tracking.FrfChannel('x_c', 'x_c', ('x_c',), tracking.COARSE_AMPLITUDE)
    stepped = tracking.frequency_response(micromill, [([channel], False)], lines, workers=1)['x_c']
    assert frf['bandwidth_hz'] == pytest.approx(tracking.bandwidth(lines, np.abs(stepped)), rel=0.10)
    assert frf['crossover_hz'] is None                  # sliding mode: not a law of the error alone


def test_the_lugre_curve_of_two_directions_is_their_means_and_their_stribeck_velocity():
    """Eq. (4.41) with omega1 = omega2 = W is Eq. (4.59) with Omega_s = W: two directions with
    the same W give back their mean levels (Eqs. 4.60, 4.61) and W."""
    from machine_ctrl.identification.rigid_body import StribeckFit, SteadyFrictionFit, lugre_curve
    curves = (StribeckFit(FitStatus.OK, '', 36.0, 40.0, 3e-3, 3e-3, 0.0),
              StribeckFit(FitStatus.OK, '', 29.0, 27.0, 3e-3, 3e-3, 0.0))
    curve = lugre_curve(SteadyFrictionFit(FitStatus.OK, '', 25.0, curves), np.geomspace(5e-5, 0.1, 10))
    assert (curve.static, curve.coulomb) == (32.5, 33.5)
    assert curve.stribeck_velocity == pytest.approx(3e-3, rel=1e-4)


def _belief_file(machine, result, directory):
    from machine_ctrl.experiments.identify import yaml_fragment
    path = directory / f'{result["axis"]}.yaml'
    path.write_text(yaml_fragment(machine, result))
    return path


def test_the_yaml_fragment_is_a_belief_file_the_machine_loads_with(micromill, x_c, tmp_path):
    """The fragment sets the controllers' values (the drive's mass and b, the LuGre
    feed-forward's curve, Eqs. 4.60, 4.61, and bristles) and leaves hw_sim's truth as it was."""
    axis = load_machine(micromill.yaml_path, belief=[_belief_file(micromill, x_c, tmp_path)]).axis('x_c')
    steady, before = x_c['steady'], micromill.axis('x_c')
    assert axis.drive.mass == pytest.approx(x_c['rigid_body'].mass.value, rel=1e-4)
    assert axis.drive.damping == pytest.approx(steady.viscous, rel=1e-4)
    feedforward, bristles = axis.control.lugre_feedforward, x_c['bristles']
    assert feedforward.coulomb == pytest.approx(np.mean([c.coulomb for c in steady.curves]), rel=1e-4)
    assert feedforward.static == pytest.approx(np.mean([c.static for c in steady.curves]), rel=1e-4)
    assert feedforward.sigma0 == pytest.approx(bristles.sigma0, rel=1e-4)
    assert feedforward.sigma1 == pytest.approx(bristles.sigma1, rel=1e-4)
    assert axis.plant == before.plant, 'the fragment changed the truth hw_sim simulates'


@pytest.mark.parametrize('axis', ['x_c', 'y_c'])
def test_the_observer_from_the_identified_model_is_within_10_percent_of_the_true_models(axis, x_c, y_c):
    """Every gain of K_obs (Eqs. 4.30-4.37) designed from the identified m, b and the run's
    resolutions within 10 % of the one from hw_sim's true m, b and resolutions (measured
    within 1.9 %); the resolutions read from the run are the config's."""
    result = {'x_c': x_c, 'y_c': y_c}[axis]
    designs = result['observer']
    assert designs['identified'].status is designs['true'].status is FitStatus.OK
    np.testing.assert_allclose(designs['identified'].gain, designs['true'].gain, rtol=0.10)
    np.testing.assert_allclose(designs['identified'].noise, designs['true'].noise, rtol=1e-6)


def test_the_circle_with_identified_values_against_the_nominal(micromill, x_c, y_c, tmp_path, capsys):
    """[8/8] "Done when": Table 6.1's circle (its first 4 s, SMC and dual stage, each beside
    its at-rest twin) with the controllers' values identified for x_c and y_c, as `machine-ctrl
    experiment circle --identified` takes them; hw_sim's truth is the same in both. The dual
    stage's every statistic within 10 % of the nominal run's. SMC's are not worse by more than
    10 %, and its maxima fall by more than half: the identified feed-forward has the plant's
    bristles (sigma0 9e6 N/m), the nominal one Table 4.3's tuned 9e5 N/m (README
    "Identification": the issue's "within 10 %" does not hold for SMC, for this reason)."""
    from machine_ctrl.app import cli
    from machine_ctrl.experiments.tracking import contouring
    files = [_belief_file(micromill, result, tmp_path) for result in (x_c, y_c)]
    identified = load_machine(micromill.yaml_path, belief=files)
    assert identified.axis('y_c').drive.mass == pytest.approx(y_c['rigid_body'].mass.value, rel=1e-4)
    nominal, ours = (contouring(machine, 'circle', steps=40_000, workers=1) for machine in (micromill, identified))
    for key, value in nominal['dsfd'].items():
        assert ours['dsfd'][key] == pytest.approx(value, rel=0.10), ('dsfd', key)
    for key, value in nominal['smc'].items():
        assert ours['smc'][key] <= 1.10 * value, ('smc', key)
    for key in ('max_x_tracking', 'max_y_tracking', 'max_contour'):
        assert ours['smc'][key] < 0.5 * nominal['smc'][key], key
    assert cli.main(['experiment', 'circle', '--steps', '200', '--jobs', '1', '--json', '--identified', str(files[0]),
                     '--identified', str(files[1])]) == 0
    out = capsys.readouterr()
    assert f"the controllers' values from {files[0]}, {files[1]}" in out.err
    assert json.loads(out.out)["identified"] == [str(f) for f in files]     # said in the result too (absolute)


def test_one_command_identifies_the_flexure_stage_and_the_piezo_stage(fts_lathe, robot_piezo, tmp_path):
    """[8/8] part 3: `machine-ctrl identify` on fts_lathe's W runs Ding's stepped sine and
    grey-box fit (each parameter within 5 % of what hw_sim simulates, the [3/8] tolerance), on
    robot_piezo's px Sörnmo's chirp and N4SID (the first eigenfrequency within 5 % of the
    plant's lowest mode). Each `--out` is a belief file of the model the axis's model-based
    law designs from: the flexure stage's drive mass, damping and flexure (its H2 law), the
    piezo stage's drive.modes (its LQG: each mode within 1 % / 10 % of the plant's frequency /
    damping); the shipped configs hold exactly these, the plants untouched."""
    from machine_ctrl.app import cli
    from machine_ctrl.experiments.identify import identify_axis, yaml_fragment
    flexure = identify_axis(fts_lathe, 'w')
    assert flexure['status'] == 'ok' and flexure['method'] == 'frf_grey_box', flexure['reason']
    assert len(flexure['rows']) == 6, flexure['rows']          # Table 5-2's six parameters
    for name, _, true, value in flexure['rows']:
        assert value == pytest.approx(true, rel=0.05), name
    piezo = identify_axis(robot_piezo, 'px')
    assert piezo['status'] == 'ok' and piezo['method'] == 'subspace', piezo['reason']
    (_, seed_order, _, order), _, (_, _, true_hz, found_hz) = piezo['rows']
    assert order == seed_order == 4 and found_hz == pytest.approx(true_hz, rel=0.05)
    assert cli.main(['identify', 'w', '--machine', 'fts_lathe', '--out', str(tmp_path / 'w.yaml')]) == 0
    other = tmp_path / 'other_w.yaml'      # a model the written file must replace, each number
    other.write_text('axes:\n  w:\n    drive:\n      mass: 1.0\n      damping: 1.0\n      flexure: {stiffness: 1.0, '
                     'secondary_mass: 1.0, secondary_stiffness: 1.0, secondary_damping: 1.0}\n')
    believed = load_machine('fts_lathe', belief=[other, tmp_path / 'w.yaml']).axis('w')
    assert believed == fts_lathe.axis('w')        # the shipped config holds exactly these (README)
    model = flexure['model']
    assert (believed.drive.mass, believed.drive.flexure.stiffness) == (pytest.approx(model['m12'], rel=1e-4),
                                                                      pytest.approx(model['k2'], rel=1e-4))
    assert cli.main(['identify', 'px', '--machine', 'robot_piezo', '--out', str(tmp_path / 'px.yaml')]) == 0
    other = tmp_path / 'other.yaml'        # a model the written file must replace, modes and real pole
    other.write_text('axes:\n  px:\n    drive:\n      modes: [{omega: 200.0, zeta: 0.2}]\n      real_pole: 50.0\n')
    believed = load_machine('robot_piezo', belief=[other, tmp_path / 'px.yaml']).axis('px')
    assert believed.plant == robot_piezo.axis('px').plant and believed.drive.real_pole == 0.0
    assert [(m.omega, m.zeta) for m in believed.drive.modes] == [
        (pytest.approx(m['omega'], rel=1e-5), pytest.approx(m['zeta'], rel=1e-3)) for m in piezo['model']['modes']]
    for found, true in zip(believed.drive.modes, robot_piezo.axis('px').plant.modes, strict=True):
        assert found.omega == pytest.approx(true.omega, rel=0.01) and found.zeta == pytest.approx(true.zeta, rel=0.1)
    assert believed == robot_piezo.axis('px')        # the shipped config holds exactly these (README)
    z = identify_axis(robot_piezo, 'pz')           # with its real pole, through the library's fragment
    (tmp_path / 'pz.yaml').write_text(yaml_fragment(robot_piezo, z))
    assert load_machine('robot_piezo', belief=[tmp_path / 'pz.yaml']).axis('pz') == robot_piezo.axis('pz')


def test_an_axis_without_a_force_drive_and_friction_is_refused_and_the_command_says_why(micromill, capsys):
    from machine_ctrl.app import cli
    from machine_ctrl.experiments.identify import identify
    for axis in ('a_f', 'x_f'):
        result = identify(micromill, axis)
        assert result['status'] == 'refused', result
    assert identify(micromill, 'a_f')['reason'].endswith('a_f lacks a linear joint, guideway friction (plant.friction)')
    assert identify(micromill, 'x_f')['reason'].endswith('x_f lacks guideway friction (plant.friction)')
    assert cli.main(['identify', 'x_f']) == 1
    assert 'x_f lacks guideway friction' in capsys.readouterr().err
    assert cli.main(['identify', 'q_q']) == 2
    assert "micromill_9axis has no axis 'q_q'" in capsys.readouterr().err
