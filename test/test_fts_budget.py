"""Ding FTS error budget (machine_ctrl/experiments/fts_budget.py; seed 003_edeaa855566124b7, section 5.7).

Expected values are the seed's numbers, written here, or are computed here by code that does
not call the module (the 2-DOF eigenproblem, the characteristic polynomial, the -3 dB
crossing). Tolerances are stated where they are used.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from experiment_cli import experiment_json
from machine_ctrl.experiments import fts_budget as fb

# seed 003 Table 5-2 and the loop constants, written out again (not read from the module)
M12, K2, C2, M4, K4, C4 = 0.074, 21965.0, 2.28, 0.008, 56285.0, 6.18
HEAVY = 0.175 - 0.075            # section 5.7.3 added steel
KT = 3.6658                      # section 5.5.2
W_I = 2 * math.pi * 400e3        # Eq. (5-9), section 4.6.4
SERVO = 199.6e3                  # section 5.7.3
TAU = 3.5e-6 + 0.5 / SERVO       # section 4.4.4 + half a sample (section 4.4.3)
SETTINGS = (301.0, 468.0, 1448.0)   # section 5.7.4, Fig. 5-14 b)


@pytest.fixture(scope='module')
def result():
    r = fb.reproduce(sweep_points=13)
    assert r['status'] == 'ok', r['reason']
    return r


@pytest.fixture(scope='module')
def heavy(result):
    return result['plant']


def _undamped_modes_hz(mass):
    m = np.diag([mass, M4])
    k = np.array([[K2 + K4, -K4], [-K4, K4]])
    w2 = np.linalg.eigvals(np.linalg.solve(m, k)).real
    return np.sort(np.sqrt(w2) / (2 * math.pi))


@pytest.mark.parametrize('added', [0.0, HEAVY])
def test_plant_resonances_match_the_table_5_2_modes(added):
    # light damping (zeta <= ~0.15 for c4) moves |pole| off the undamped frequency by well under 2 %
    ours = fb.mode_frequencies(fb.FtsPlant(added_mass=added))
    expected = _undamped_modes_hz(M12 + added)
    assert ours.shape == (2,)
    np.testing.assert_allclose(ours, expected, rtol=0.02)


def _polys(plant, pid):
    """Loop factors written from the equations of motion (C-1..C-4 with k1 rigid, m3 ground)."""
    m = M12 + plant.added_mass
    wc = 2 * math.pi * plant.sensor_bandwidth_hz
    det = np.polysub(np.polymul([m, C2 + C4, K2 + K4], [M4, C4, K4]), np.polymul([C4, K4], [C4, K4]))
    return {
        'pid': ([pid.kd + pid.kp * pid.tf, pid.kp + pid.ki * pid.tf, pid.ki], [pid.tf, 1.0, 0.0]),
        'hi': ([W_I ** 2], [1.0, 2 * 0.707 * W_I, W_I ** 2]),
        'g': ([M4, C4, K4], det),
        'hc': ([wc ** 2], [1.0, math.sqrt(2) * wc, wc ** 2]),
    }


def _loop(plant, pid, f):
    s = 2j * math.pi * f
    p = _polys(plant, pid)
    val = np.ones_like(s) * plant.sensitivity * KT * np.exp(-s * TAU)
    for num, den in p.values():
        val = val * np.polyval(num, s) / np.polyval(den, s)
    return val


def _bandwidth(f, t):
    mag = 20 * np.log10(np.abs(t))
    i = int(np.nonzero(mag < -3.0103)[0][0])
    lf = np.log(f)
    return float(np.exp(lf[i - 1] + (-3.0103 - mag[i - 1]) * (lf[i] - lf[i - 1]) / (mag[i] - mag[i - 1])))


def _char_roots(plant, pid, w0=1e4):
    """Closed-loop roots (in units of w0 rad/s) of Dpid Dhi Dg Dhc Dpade + S KT N...; Pade (2,2) delay."""
    p = dict(_polys(plant, pid))
    p['pade'] = ([TAU ** 2 / 12, -TAU / 2, 1.0], [TAU ** 2 / 12, TAU / 2, 1.0])

    def scaled(c):
        c = np.asarray(c, float)
        n = len(c) - 1
        return c * w0 ** np.arange(n, -1, -1)
    num, den = np.array([plant.sensitivity * KT]), np.array([1.0])
    for n_, d_ in p.values():
        num, den = np.polymul(num, scaled(n_)), np.polymul(den, scaled(d_))
    return np.roots(np.polyadd(den, num))


@pytest.mark.parametrize('target', SETTINGS)
def test_settings_are_stable_and_hit_the_bandwidths(result, heavy, target):
    pid = result['settings'][target]['gains']['pid']
    roots = _char_roots(heavy, pid)
    assert len(roots) == 12
    assert roots.real.max() < 0, f'{target} Hz setting unstable: {roots[roots.real >= 0]}'
    # the gains are solved to 1e-9; an independent loop on another grid agrees to interpolation
    # error (< 0.1 %); 1 % leaves room for nothing else
    f = np.logspace(0, math.log10(SERVO / 2), 20001)
    loop = _loop(heavy, pid, f)
    assert _bandwidth(f, loop / (1 + loop)) == pytest.approx(target, rel=0.01)


def test_global_gain_grows_with_bandwidth(result):
    kg = [result['settings'][b]['gains']['kg'] for b in SETTINGS]
    assert kg[0] < kg[1] < kg[2]


def _row(result, start):
    rows = [r for r in result['rows'] if r['name'].startswith(start)]
    assert len(rows) == 1, start
    return rows[0]


def test_calibration_figure_is_met(result):
    # the one calibration (section 5.7.3, Fig. 5-16): closed form, so to the grid's accuracy
    assert result['settings'][468.0]['budget']['following']['total']['rms'] == pytest.approx(0.83e-9, rel=1e-3)


@pytest.mark.parametrize('start, seed, tol', [
    # 30 %: the brief's threshold for "reproduced"; the real RMS hinges on the assumed 15 kHz
    # sensor band (10 / 20 kHz give +18 / -11 %), the p-v on 64 records of 4096 samples
    ('real RMS @468', 0.23, 0.30),
    ('following p-v @468', 6.0, 0.30),
    ('optimum bandwidth 0.175 kg', 468.0, 0.30),
])
def test_reproduced_figures(result, start, seed, tol):
    row = _row(result, start)
    assert row['ours'] == pytest.approx(seed, rel=tol)
    assert row['ratio'] == pytest.approx(row['ours'] / seed, rel=1e-9)


def test_rows_off_by_more_than_30_percent_say_why(result):
    for row in result['rows']:
        seed = np.mean(row['seed']) if isinstance(row['seed'], tuple) else row['seed']
        off = not (abs(row['ours'] / seed - 1) <= 0.30) if not isinstance(row['seed'], tuple) else \
            not (row['seed'][0] * 0.7 <= row['ours'] <= row['seed'][1] * 1.3)
        assert off == row['off'], row['name']
        if off:
            assert len(row['note']) > 20, row['name']


def test_following_error_overreports_high_and_underreports_low(result):
    b = result['settings'][468.0]['budget']
    f = b['f']
    fol, real = b['following']['total'], b['real']['total']
    assert fol['rms'] > 2 * real['rms']                        # section 5.7.3: 0.83 vs 0.23 nm
    low, high = f < 100.0, f > 2000.0

    def power(psd, band):
        return np.trapezoid(psd[band], f[band])
    assert power(fol['psd'], low) < power(real['psd'], low)    # under-reports at low frequency (section 5.9)
    assert power(fol['psd'], high) > 10 * power(real['psd'], high)   # over-reports at high frequency
    # and point-wise on the sensor path: |S|^2 < |T|^2 well inside the bandwidth
    s = b['following']['sensor']['psd'][f < 50.0]
    r = b['real']['sensor']['psd'][f < 50.0]
    assert np.all(s < r)


def test_ground_is_a_small_fraction_and_sensor_dominates_at_high_bandwidth(result):
    # section 5.7.4 / Fig. 5-17
    for bw in SETTINGS:
        real = result['settings'][bw]['budget']['real']
        assert real['ground']['rms'] ** 2 < 0.01 * real['total']['rms'] ** 2
    real = result['settings'][1448.0]['budget']['real']
    assert real['sensor']['rms'] > real['current']['rms']


def test_cas_ends_at_the_rms_and_grows(result):
    b = result['settings'][301.0]['budget']
    for kind in ('real', 'following'):
        for src, v in b[kind].items():
            assert np.all(np.diff(v['cas']) >= 0)
            assert v['cas'][-1] == v['rms']
            # Eq. (5-17) by an independent integration of the PSD
            assert v['rms'] == pytest.approx(math.sqrt(np.trapezoid(v['psd'], b['f'])), rel=1e-9)


@pytest.mark.parametrize('target', [468.0, 1448.0])
def test_parseval_psd_integral_equals_time_domain_rms(heavy, result, target):
    pid = result['settings'][target]['gains']['pid']
    budget = result['settings'][target]['budget']
    sim = fb.simulate_sensor_noise(heavy, pid, duration=0.1, realizations=32, seed=11)
    assert sim['status'] == 'ok', sim['reason']
    assert sim['following'].shape == (32, int(round(0.1 * SERVO)))
    # following error: broadband, ~2e4 samples x 32: sampling error < 0.5 %; Tustin / Pade
    # against the exact delay and the continuous H_capa: ~2 %; so 4 %
    fol = math.sqrt(np.mean(sim['following'] ** 2))
    assert fol == pytest.approx(budget['following']['sensor']['rms'], rel=0.04)
    # real error: band of ~1 kHz, 0.1 s -> ~200 independent samples per run; 32 runs: ~2 % (1 sigma)
    real = math.sqrt(np.mean(sim['real'] ** 2))
    assert real == pytest.approx(budget['real']['sensor']['rms'], rel=0.07)


def test_failures_are_reported_not_raised(heavy):
    bad = fb.calibrate(heavy, target_nm=0.01)          # the current noise alone exceeds 0.01 nm
    assert bad['status'] == 'failed' and 'no sensitivity' in bad['reason']
    unreachable = fb.gains_for_bandwidth(heavy, 60e3)
    assert unreachable['status'] == 'failed' and unreachable['reason']
    for f in (np.array([[1.0, 2.0]]), np.array([5.0, 1.0]), np.array([0.0, 1.0])):
        broken = fb.error_budget(heavy, fb.Pid(), f=f)
        assert broken['status'] == 'failed' and 'frequency grid' in broken['reason']
    massless = fb.error_budget(fb.FtsPlant(m12=0.0), fb.Pid())
    assert massless['status'] == 'failed' and 'm12' in massless['reason']
    assert fb.format_table({'status': 'failed', 'reason': 'x'}).endswith('x')
    assert fb.plots({'status': 'failed'}, '/nonexistent') == []


def test_table_and_plots(result, tmp_path):
    text = fb.format_table(result)
    for needle in ('0.83', '0.23', 'S_capa', '301', '468', '1448'):
        assert needle in text
    paths = fb.plots(result, tmp_path)
    assert len(paths) == 2
    for p in paths:
        with open(p, 'rb') as fh:
            assert fh.read(8) == b'\x89PNG\r\n\x1a\n'


def test_the_command_prints_the_figures_and_writes_the_plots(tmp_path):
    """`machine-ctrl experiment fts-budget --json --plots DIR`: the CLI wiring."""
    data = experiment_json('fts-budget', tmp_path)
    assert data['calibration']['parameter'] == 'S_capa'
    seeds = {row['name']: row['seed'] for row in data['rows']}
    assert seeds['following RMS @468 Hz [calibration]'] == 0.83 and seeds['real RMS @468 Hz'] == 0.23
    assert sorted(p.name for p in tmp_path.iterdir()) == ['fts_budget_psd_cas.png', 'fts_budget_sweep.png']
