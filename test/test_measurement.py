"""Simulated laser campaign, measurement CSV validation and quintic fits (thesis Eqs. 5.9-5.13)."""
import json

import numpy as np
import pytest

from machine_ctrl.app import cli
from compensation.error_map import load_error_map
from compensation.error_model import ErrorKinematics
from compensation.fitting import fit_map
from compensation.measurement import (NOISE_DISPLACEMENT, MeasurementError, Series, campaign, read_csv,
                                      write_csv)


@pytest.fixture(scope='module')
def truth(micromill):
    true_map = load_error_map(micromill.simulation.error_map_path(micromill.yaml_path), micromill.axis_names)
    return ErrorKinematics.from_config(micromill, true_map), true_map


@pytest.fixture(scope='module')
def measured(truth, micromill):
    return campaign(*truth, micromill.simulation.seed)


def test_campaign_is_the_thesis_procedure(measured, truth):
    by_axis = {}
    for s in measured:
        by_axis.setdefault(s.axis, []).append(s.error)
        assert s.values.shape[0] == 6                                    # 6 repeats
        np.testing.assert_allclose(np.diff(s.positions), 1e-3, atol=1e-12)  # 1 mm steps
    assert by_axis == {'x_c': ['dx', 'dy', 'dz', 'ey', 'ez'],            # no roll
                       'y_c': ['dx', 'dy', 'dz', 'ex', 'ez'],
                       'z_c': ['dx', 'dy', 'dz', 'ex', 'ey']}
    x = next(s for s in measured if (s.axis, s.error) == ('x_c', 'dx'))
    assert len(x.positions) == 81 and x.positions[0] == -0.04
    noise = x.values - truth[0].axis_errors('x_c', x.positions)[:, 0]
    assert 0.8 * NOISE_DISPLACEMENT < noise.std() < 1.2 * NOISE_DISPLACEMENT


def test_campaign_is_seeded(truth, measured):
    again = campaign(*truth, 1)
    other = campaign(*truth, 2)
    assert len(again) == len(measured) > 0
    assert all((a.values == b.values).all() for a, b in zip(measured, again))
    assert not (measured[0].values == other[0].values).all()


def test_csv_round_trip(tmp_path, measured, micromill):
    path = tmp_path / 'm.csv'
    write_csv(path, measured, 'a comment')
    back = read_csv(path, micromill.axis_names)
    assert len(back) == len(measured) > 0
    for a, b in zip(measured, back):
        assert (a.axis, a.error) == (b.axis, b.error)
        assert (a.positions == b.positions).all() and (a.values == b.values).all()


def test_fit_recovers_an_exact_quintic(micromill):
    q = np.linspace(-0.04, 0.04, 81)
    u = q / 0.04
    coefficients = (1e-7, -2e-7, 3e-7, 4e-7, -5e-7, 6e-7)
    values = sum(c * u ** (5 - i) for i, c in enumerate(coefficients))
    model, residuals = fit_map([Series('x_c', 'dy', q, np.tile(values, (6, 1)))])
    np.testing.assert_allclose(model.axes['x_c'].coefficients['dy'], coefficients, rtol=0, atol=1e-18)
    assert residuals[0].rms < 1e-18 and residuals[0].repeatability < 1e-20


def test_fit_of_the_noisy_campaign_is_close_to_the_truth(measured, truth):
    model, residuals = fit_map(measured)
    for s in measured:
        i = ('dx', 'dy', 'dz', 'ex', 'ey', 'ez').index(s.error)
        got = model.axes[s.axis].evaluate(s.positions)[:, i]
        want = truth[0].axis_errors(s.axis, s.positions)[:, i]
        assert np.abs(got - want).max() < (0.05e-6 if i < 3 else 0.5e-6), (s.axis, s.error)
    assert all(r.positions >= 81 and r.repeats == 6 for r in residuals)


def _write(path, text):
    path.write_text(text)
    return path


GOOD = ''.join(f'x_c,dx,{q / 1000!r},1,1e-7\n' for q in range(6))


@pytest.mark.parametrize('body, problem', [
    ('axis,error,position,value\n' + GOOD, ':1: missing column(s) repeat'),
    ('axis,error,position,repeat,value\n' + GOOD.replace('0.003,1,1e-7', '0.003,1,nan'), ':5: value is nan'),
    ('axis,error,position,repeat,value\n' + GOOD.replace('0.003,1,1e-7', '0.003,1,abc'), ":5: value 'abc' is not a number"),
    ('axis,error,position,repeat,value\n' + ''.join(GOOD.splitlines(True)[:5]), 'needs at least 6'),
    ('axis,error,position,repeat,value\n' + GOOD.replace('0.003,', '0.0001,'), ':5: x_c dx repeat 1: position'),
    ('axis,error,position,repeat,value\n' + GOOD.replace('x_c,dx,0.003', 'w_c,dx,0.003'), ":5: unknown axis 'w_c'"),
    ('axis,error,position,repeat,value\n' + GOOD + GOOD.replace(',1,', ',2,').replace('0.005', '0.006'),
     'repeat 2 has other positions'),
])
def test_bad_measurement_files_are_refused(tmp_path, micromill, body, problem):
    path = _write(tmp_path / 'bad.csv', body)
    with pytest.raises(MeasurementError) as info:
        read_csv(path, micromill.axis_names)
    assert problem in str(info.value) and str(path) in str(info.value)


def test_fit_errors_command(tmp_path, measured, micromill, capsys):
    csv_path, model_path = tmp_path / 'm.csv', tmp_path / 'model.yaml'
    write_csv(csv_path, measured)
    assert cli.main(['fit-errors', str(csv_path), '--out', str(model_path), '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out['residuals']) == 15
    reloaded = load_error_map(model_path, micromill.axis_names)
    assert reloaded.axes == fit_map(measured)[0].axes                    # written exactly
    bad = _write(tmp_path / 'bad.csv', 'axis,error\n')
    assert cli.main(['fit-errors', str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith('machine-ctrl: ') and err.count('\n') == 1 and 'missing column' in err
