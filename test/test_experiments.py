"""The [2/7] acceptance criteria on the simulated machine (full-length runs, ~1 min)."""
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from machine_ctrl.experiments import tracking as experiments
from machine_ctrl.model.config import load_machine
from machine_ctrl.experiments.tracking import STAT_KEYS, THESIS


@pytest.fixture(scope='module')
def circle(micromill):
    return experiments.contouring(micromill, 'circle')


def test_circle_dual_stage_beats_sliding_mode_as_in_the_thesis(circle):
    """The dual stage takes SMC's maxima down by the thesis's factors or more. With the plant's
    workpiece its maxima are the table's noise floor (README "Experiments"): then the factor
    says how far above that floor SMC's errors stand, which no better coupling could lower."""
    smc, dsfd = circle['smc'], circle['dsfd']
    assert smc['max_contour'] / dsfd['max_contour'] >= 2.5          # thesis 2.67 -> 0.858 um
    assert smc['max_y_tracking'] / dsfd['max_y_tracking'] >= 3.0    # thesis 1.72 -> 0.377 um


# How far each compared Table 6.1 cell moves when the one plant value chosen for it is halved or
# doubled (README "Sensitivity", the circle's rows): SMC maxima 0.67 / 1.37 (sigma0), SMC means
# 0.63 / 1.81 (mostly the force noise), DSFD means 0.51 / 2.00 (the force noise in proportion).
SPAN = {('smc', 'max'): 1.5, ('smc', 'mean'): 1.85, ('dsfd', 'mean'): 2.0}
# The one cell outside its span: the thesis's DSFD x and y means differ by 4x (0.198 / 0.049 um),
# ours are alike (one assumed noise on both of the table's translations): x needs 2.06x our noise
BEYOND_SPAN = {('dsfd', 'mean_x_tracking'): 2.1}
# The circle's cells at the noise floor, pinned from a run (as README "Experiments"): the dual
# stage's maxima, 0.529 / 0.485 / 0.548 um against 0.503 / 0.497 / 0.528 um with the machine
# holding the start point (within one 0.04 um count: the table's force-noise excursion, which the
# coarse motion does not change); SMC's maxima stand 5x above theirs (2.72 / 1.83 / 2.45 um), its
# means 1.2-1.3x (0.113-0.129 um against 0.095-0.097 um). DSFD's means are only just above theirs
# (0.0961 / 0.0971 / 0.09687 against 0.0949 / 0.0968 / 0.09685 um: the force noise, README
# "Sensitivity"), and compared. A rule that skips any other cell skips a result, and fails here.
CIRCLE_FLOOR = {'smc': set(), 'dsfd': {'max_x_tracking', 'max_y_tracking', 'max_contour'}}


def test_circle_every_result_within_what_its_calibrated_value_spans_of_table_6_1(circle):
    """Each compared cell within the factor by which it moves when the one plant value set for
    it is halved or doubled (SPAN, [8/8] part 4): the maxima rest on the bristles' sigma0, set
    against these very maxima; the means on the table's force noise, set against CIRP's
    ~200 nm. A closer match would say nothing: those values were chosen to come near. (Before:
    within 3x for every cell.) The DSFD x mean is outside its span (BEYOND_SPAN: 1/0.485 =
    2.06x), which no noise level within 2x meets together with the y mean (1.97x); it is held
    at 2.1x and said. Measured ratios: SMC 0.57-1.07 (means), 0.92-1.07 (maxima); DSFD means
    0.485 / 1.97 / 0.80. Cells at the noise floor (no larger than with the machine at rest:
    tracking.noise_floor) are not results: not compared."""
    assert {mode: set(keys) for mode, keys in circle['noise_floor'].items()} == CIRCLE_FLOOR
    for mode in ('smc', 'dsfd'):
        for key, thesis in zip(STAT_KEYS, THESIS['circle'][mode]):
            if key in CIRCLE_FLOOR[mode]:
                continue
            factor = BEYOND_SPAN.get((mode, key), SPAN[(mode, key.split('_')[0])])
            ratio = circle[mode][key] / thesis
            assert 1 / factor <= ratio <= factor, f'{mode} {key}: {circle[mode][key]:.3f} um vs thesis {thesis} um'


def test_frf_bandwidths(micromill):
    """The closed-loop -3 dB points, and like for like with the thesis's numbers (its Fig.
    4.10 text: ~30 Hz, lambda; 250 Hz, the table's designed open-loop crossover omega_m):
    the lead-lag axes' measured open-loop crossover below their design by the workpiece the
    plant carries and the design does not (2.55 kg against 2.3: between sqrt and linear in
    the mass ratio, 0.90-0.95; measured 0.92)."""
    result = experiments.frf(micromill)
    bw = result['bandwidth_hz']
    for axis in ('x_c', 'y_c', 'z_c'):
        assert 20 <= bw[axis] <= 45, (axis, bw[axis])
    for axis in ('x_f', 'y_f', 'z_f'):
        assert 180 <= bw[axis] <= 400, (axis, bw[axis])
    assert abs(bw['x_dual'] / bw['x_f'] - 1) <= 0.2
    assert set(result['crossover_hz']) == {'x_f', 'y_f', 'z_f'}           # the lead-lag axes: error feedback
    assert result['design_hz']['x_c'] == pytest.approx(200.0 / (2 * math.pi))
    for axis in ('x_f', 'y_f'):
        ratio = result['crossover_hz'][axis] / result['design_hz'][axis]
        assert 2.3 / 2.55 - 0.01 <= ratio <= math.sqrt(2.3 / 2.55), (axis, ratio)


def test_the_open_loop_crossover_of_a_table_as_designed_is_omega_m(micromill, tmp_path):
    """L = T/(1 - T) from the measured closed loop: with the plant's table at the 2.3 kg its
    lead-lag was designed for, x_f and y_f cross over within 3 % of omega_m = 1/(T sqrt(alpha))
    (Eq. 4.74; measured +1.6 %)."""
    import shutil
    text = micromill.yaml_path.read_text()
    truth = '      mass: 2.55               # kg, the truth'
    assert text.count(truth) == 3
    (tmp_path / 'm.yaml').write_text(text.replace(truth, '      mass: 2.3 # ').replace(
        'error_map: ../error_maps/', f'error_map: {micromill.yaml_path.parent.parent}/error_maps/'))
    shutil.copy(micromill.urdf_path, tmp_path)
    as_designed = load_machine(tmp_path / 'm.yaml')
    result = experiments.frf(as_designed, np.geomspace(150.0, 350.0, 9), workers=1)
    for axis in ('x_f', 'y_f'):
        assert result['crossover_hz'][axis] == pytest.approx(result['design_hz'][axis], rel=0.03), axis


def test_runs_in_other_processes_give_the_same_numbers(micromill):
    """experiments/parallel.py: the contouring runs and the frf points computed in two
    processes equal those computed here one after another, bit for bit."""
    here = experiments.contouring(micromill, 'square', steps=2000, workers=1)
    assert experiments.contouring(micromill, 'square', steps=2000, workers=2) == here
    frequencies = [20.0, 300.0]
    assert experiments.frf(micromill, frequencies, workers=2) == experiments.frf(micromill, frequencies, workers=1)


def test_experiment_command_json_is_one_object():
    """The CLI wiring, on the first 3000 steps of the square (the three modes, the micromill
    having a contour_control section, and their at-rest runs; the whole square runs in
    test_square_artefact.py)."""
    exe = str(Path(sys.executable).parent / 'machine-ctrl')
    result = subprocess.run([exe, 'experiment', 'square', '--json', '--steps', '3000'], capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout)
    assert set(data) == {'smc', 'dsfd', 'ccc', 'measured', 'true', 'at_rest', 'noise_floor', 'command_use',
                         'encoder_count_um', 'steps', 'notes', 'identified'}
    assert data['identified'] == []                    # the config's own values: no belief file
    # the first 3000 steps run along the square's first side, x moving, y held: y's cells and the
    # contour error (y's offset there) read what the machine reads at rest (bit for bit in SMC and
    # DSFD, 0.103 / 0.380 um), and the dual stage's max x is within one count of its at-rest one
    # (0.379 against 0.340 um); the coupled mode's mean contour, 0.102 um, is below its at-rest
    # 0.109 um. Pinned from a run: the other cells (SMC's x, DSFD's mean x at 0.075 against
    # 0.072 um, the coupled x) are results
    assert {mode: set(keys) for mode, keys in data['noise_floor'].items()} == {
        'smc': {'mean_y_tracking', 'max_y_tracking', 'max_contour'},
        'dsfd': {'mean_y_tracking', 'max_x_tracking', 'max_y_tracking', 'max_contour'},
        'ccc': {'mean_y_tracking', 'mean_contour', 'max_y_tracking', 'max_contour'}}
    assert set(data['command_use']) == {'smc', 'dsfd', 'ccc'} and max(data['command_use'].values()) < 1.0
    for mode in ('smc', 'dsfd', 'ccc'):
        assert set(data[mode]) == set(data['measured'][mode]) == set(data['true'][mode]) == set(STAT_KEYS)
        for key in STAT_KEYS:      # a figure at the noise floor is not reported as a result: null
            expected = None if key in data['noise_floor'][mode] else data['measured'][mode][key]
            assert data[mode][key] == expected, (mode, key)
    assert 'square smc' in result.stderr and 'square smc at rest' in result.stderr   # progress goes to stderr
    assert data['steps'] == 3000


def test_steps_and_jobs_must_be_whole_numbers_and_steps_only_for_the_contours(capsys):
    from machine_ctrl.app import cli
    for option in ('--steps', '--jobs'):
        for bad in ('0', '-5', '2.5', 'many'):
            with pytest.raises(SystemExit) as info:
                cli.build_parser().parse_args(['experiment', 'square', option, bad])
            assert info.value.code == 2
            assert f"argument {option}: must be a whole number > 0, got '{bad}'" in capsys.readouterr().err
    exe = str(Path(sys.executable).parent / 'machine-ctrl')
    result = subprocess.run([exe, 'experiment', 'frf', '--steps', '10'], capture_output=True, text=True, timeout=120)
    assert result.returncode != 0 and '--steps is for circle and square' in result.stderr
