"""Bag analysis on bags written from offline runs (experiment --record), against the
experiment's own statistics, and the contour-error geometry against analytic cases."""
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from machine_ctrl.recording import analysis

STEPS = 3000


@pytest.fixture(scope='module')
def recorded(micromill, tmp_path_factory):
    """circle, 3000 steps, SMC and DSFD: (stats from experiments, bag directory)."""
    os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    from machine_ctrl.app.cli.experiment import contouring     # writes the bags (run_bag)
    directory = tmp_path_factory.mktemp('exp')
    stats = contouring(micromill, 'circle', steps=STEPS, record_dir=directory)
    return stats, directory


def test_dual_stage_errors_equal_the_experiment_statistics(recorded, micromill):
    stats, directory = recorded
    for label in ('smc', 'dsfd'):
        result = analysis.analyse(analysis.load(directory / label))
        assert result['steps'] == STEPS and result['machine'] == micromill.name
        for axis, pair in (('x', 'x_c+x_f'), ('y', 'y_c+y_f')):
            assert result['dual_stage'][pair]['mean'] * 1e6 == pytest.approx(stats[label][f'mean_{axis}_tracking'], rel=1e-9)
            assert result['dual_stage'][pair]['max'] * 1e6 == pytest.approx(stats[label][f'max_{axis}_tracking'], rel=1e-9)


def test_contour_error_of_a_line_and_a_circle():
    line = np.column_stack((np.linspace(0, 1e-2, 1001), np.zeros(1001), np.zeros(1001)))
    points = line + np.array([0.0, 3e-6, -4e-6])
    assert analysis.contour_errors(line, points, 10) == pytest.approx(np.full(1001, 5e-6), rel=1e-9)
    theta = np.linspace(0, 2 * math.pi, 20001)
    r = 0.03
    circle = np.column_stack((r * np.cos(theta), r * np.sin(theta), np.zeros_like(theta)))
    outside = circle * (1 + 1e-6 / r)                      # 1 um outside, lagging 5 samples
    lagged = np.roll(outside, 5, axis=0)
    sagitta = r * (1 - math.cos(theta[1] / 2))             # chord error of the polyline
    errors = analysis.contour_errors(circle, lagged, 50)[10:-10]
    assert np.all(np.abs(errors - 1e-6) <= sagitta + 1e-15)


def test_the_contour_error_looks_for_the_path_only_within_the_window():
    """A path that comes back beside itself: 100 steps out along x, 100 back 2 um beside the way
    out. A point of the way back (step 150), 1.5 um off it towards the way out, is 1.5 um from
    its own part of the path, within a 10-step window; the way out's step 49 beside it, 0.5 um
    away, counts only once the window reaches it."""
    out = np.column_stack((np.linspace(0.0, 1e-3, 100), np.zeros(100), np.zeros(100)))
    back = out[::-1] + [0.0, 2e-6, 0.0]
    path = np.vstack((out, back))
    points = path.copy()
    points[150] = path[150] - [0.0, 1.5e-6, 0.0]               # on the way back, 1.5 um towards the way out
    errors = analysis.contour_errors(path, points, 10)
    assert errors[150] == pytest.approx(1.5e-6, rel=1e-9)      # its own part only: the way out is 40 steps away
    assert analysis.contour_errors(path, points, 150)[150] == pytest.approx(0.5e-6, rel=1e-9)   # reaches step 49
    assert np.all(np.delete(errors, 150) == 0.0)
    with pytest.raises(ValueError, match='one row per step each, got 200 and 199'):
        analysis.contour_errors(path, points[:-1], 10)


def _cli(*args):
    return subprocess.run([sys.executable, '-m', 'machine_ctrl.app.cli', *map(str, args)], capture_output=True,
                          text=True, env={**os.environ, 'AMENT_PREFIX_PATH': sys.prefix})


def test_compare_two_bags_json_table_and_plots(recorded, tmp_path):
    stats, directory = recorded
    result = _cli('analyze', directory / 'smc', directory / 'dsfd', '--json', '--plots', tmp_path / 'plots')
    assert result.returncode == 0, result.stderr
    runs = json.loads(result.stdout)['runs']
    assert [r['source'] for r in runs] == [str(directory / 'smc'), str(directory / 'dsfd')]
    assert runs[0]['dual_stage']['x_c+x_f']['max'] * 1e6 == pytest.approx(stats['smc']['max_x_tracking'], rel=1e-9)
    for name in ('errors.png', 'path_xy.png', 'limits.png'):
        data = (tmp_path / 'plots' / name).read_bytes()
        assert data[:8] == b'\x89PNG\r\n\x1a\n' and len(data) > 10_000
    table = _cli('analyze', directory / 'smc', directory / 'dsfd')
    assert table.returncode == 0 and '[1]/[2]' in table.stdout and 'x_c+x_f max [um]' in table.stdout


def test_bad_machine_and_too_many_bags(recorded):
    _, directory = recorded
    bad = _cli('analyze', directory / 'smc', '--machine', 'no_such_machine')
    assert bad.returncode == 2 and len(bad.stderr.splitlines()) == 1
    many = _cli('analyze', directory / 'smc', directory / 'smc', directory / 'smc')
    assert many.returncode == 2 and 'one bag or two' in many.stderr
