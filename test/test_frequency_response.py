"""The H1 frequency response with coherence (machine_ctrl/identification/frequency_response.py,
issue [8/8] part 1): on a known linear filter the estimate and its coherence against the
filter's own response (scipy.signal.freqz) and the coherence that the known noise implies;
the bandwidths against closed forms; the excitation's band, slope and rms; the refusals."""
import math

import numpy as np
import pytest
from scipy import signal

from machine_ctrl.identification import frequency_response as fr
from machine_ctrl.identification.status import FitStatus

RATE = 1000.0
CUTOFF = 50.0                                   # Hz: the Butterworth's -3 dB point by its design
B, A = signal.butter(2, CUTOFF, fs=RATE)


def filtered(noise_rms, seconds=200.0, seed=5):
    """White excitation (rms 1) through the filter, white noise of `noise_rms` added to the output."""
    rng = np.random.default_rng(seed)
    r = rng.standard_normal(int(seconds * RATE))
    return r, signal.lfilter(B, A, r) + noise_rms * rng.standard_normal(len(r))


def test_the_estimate_and_its_coherence_are_the_filters_and_the_noises():
    """H1 within 5 % and 3 degrees of the filter where the coherence is 0.9 or more (its scatter
    there ~1.2 %: sqrt((1 - g2) / (2 n g2))); the coherence
    near |H|^2 S_rr / (|H|^2 S_rr + S_nn), what the noise added implies: 0.02 rms over the lines,
    none off by more than 0.12 (an estimate from 389 averages scatters by ~0.025 where it is
    about 0.5: measured 0.013 rms, 0.087 at most)."""
    noise = 0.1
    r, y = filtered(noise)
    found = fr.estimate(r, y, RATE, 1024)
    assert found.status is FitStatus.OK, found.reason
    assert found.segments == 1 + (len(r) - 1024) // 512
    _, h = signal.freqz(B, A, worN=found.frequencies, fs=RATE)
    implied = np.abs(h) ** 2 / (np.abs(h) ** 2 + noise ** 2)    # white r, rms 1, and white noise: equal densities
    assert np.sqrt(np.mean((found.coherence - implied) ** 2)) < 0.02
    assert np.abs(found.coherence - implied).max() < 0.12
    good = implied >= 0.9
    assert good.sum() > 80
    assert np.abs(np.abs(found.response[good]) / np.abs(h[good]) - 1).max() < 0.05
    assert np.degrees(np.abs(np.angle(found.response[good] / h[good]))).max() < 3.0
    assert found.frequencies[101] == RATE / 1024 * 102 == pytest.approx(99.6, abs=0.01)    # the line nearest 100 Hz
    assert found.at(100.0) == (found.response[101], found.coherence[101])


def test_the_bandwidth_of_the_estimate_is_the_filters_and_is_withheld_where_noise_rules():
    exact = fr.bandwidth(*_fine_response())
    assert exact == pytest.approx(CUTOFF, rel=1e-4)
    r, y = filtered(0.02)
    found, coherence = fr.coherent_bandwidth(fr.estimate(r, y, RATE, 1024), 0.9)
    assert found == pytest.approx(CUTOFF, rel=0.02) and coherence > 0.99
    r, y = filtered(1.0)                         # at the -3 dB point the noise's power equals the signal's
    found, coherence = fr.coherent_bandwidth(fr.estimate(r, y, RATE, 1024), 0.9)
    assert found is None and coherence == pytest.approx(1 / 3, abs=0.05)      # 0.5 / (0.5 + 1)


def test_the_crossover_of_an_integrator_is_its_gain_over_two_pi():
    f = np.geomspace(1.0, 1000.0, 400)
    assert fr.crossover(f, 200.0 / (2j * math.pi * f)) == pytest.approx(200.0 / (2 * math.pi), rel=1e-4)
    assert fr.crossover(f, np.full(len(f), 0.5)) is None and fr.bandwidth(f, np.ones(len(f))) is None


def test_the_coherent_band_is_the_widest_run_of_coherent_lines_in_log_frequency():
    coherence = np.array([0.95, 0.95, 0.5, 0.95, 0.95, 0.95, 0.2, 0.99, 0.99, 0.1])
    response = fr.FrequencyResponse(FitStatus.OK, '', np.arange(1.0, 11.0), np.ones(10, complex), coherence)
    assert fr.coherent_band(response, 0.9) == (1.0, 2.0)          # a factor 2; 4-6 Hz and 8-9 Hz are less
    assert fr.coherent_band(response, 0.999) is None


def test_the_excitation_is_pink_inside_its_band_and_has_its_rms():
    rng = np.random.default_rng(2)
    x = fr.band_limited_noise(200_000, RATE, (5.0, 200.0), 3e-5, rng)
    assert x.std() == pytest.approx(3e-5, rel=1e-9) and abs(x.mean()) < 1e-12
    power = np.abs(np.fft.rfft(x)) ** 2
    f = np.fft.rfftfreq(len(x), 1 / RATE)
    assert power[(f < 5.0) | (f > 200.0)].max() < 1e-20 * power.max()
    octave = [power[(f >= lo) & (f < 2 * lo)].sum() for lo in (10.0, 40.0)]
    assert octave[0] / octave[1] == pytest.approx(1.0, rel=0.15)          # 1/f: equal power per octave
    flat = fr.band_limited_noise(200_000, RATE, (5.0, 200.0), 1.0, rng, pink=False)
    spectrum = np.abs(np.fft.rfft(flat)) ** 2
    assert spectrum[(f >= 10) & (f < 20)].mean() / spectrum[(f >= 100) & (f < 110)].mean() == pytest.approx(1.0, rel=0.15)


@pytest.mark.parametrize('r, y, segment, reason', [
    (np.ones(5000), np.ones(4999), 256, 'equally long'),
    (np.full(5000, np.nan), np.ones(5000), 256, 'NaN or inf'),
    (np.arange(1000.0), np.ones(1000), 256, 'at least 4 segments'),
    (np.ones(5000), np.arange(5000.0), 256, 'the excitation is constant'),
])
def test_data_that_cannot_give_a_response_is_refused_with_the_reason(r, y, segment, reason):
    found = fr.estimate(r, y, RATE, segment)
    assert found.status is FitStatus.REFUSED and reason in found.reason, found.reason


def _fine_response():
    f = np.geomspace(1.0, 400.0, 2000)
    return f, signal.freqz(B, A, worN=f, fs=RATE)[1]
