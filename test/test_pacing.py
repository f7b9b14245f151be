"""hw_sim/pacing.py: the latency histogram's percentiles against the exact ones of known
samples (numpy's, nearest rank), and the wall-clock schedule."""
import numpy as np
import pytest

from hw_sim.pacing import BINS, RATIO, SMALLEST, LatencyHistogram, WallClockPacer


def filled(samples):
    histogram = LatencyHistogram()
    for value in samples:
        histogram.add(float(value))
    return histogram


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_percentiles_are_never_below_the_truth_and_within_one_bin_above(seed):
    samples = np.random.default_rng(seed).lognormal(mean=np.log(3e-4), sigma=0.6, size=5000)
    histogram = filled(samples)
    for q in (50, 90, 99, 99.9):
        truth = np.percentile(samples, q, method='inverted_cdf')     # nearest rank
        assert truth <= histogram.percentile(q) <= truth * RATIO
    assert histogram.percentile(100) == histogram.maximum == samples.max()
    assert histogram.count == 5000


def test_the_ends_of_the_range():
    histogram = filled([0.0, 5e-7, 2.0])            # below the first bin's edge; above 1 s
    assert histogram.percentile(50) == pytest.approx(SMALLEST * RATIO)
    assert histogram.percentile(99) == histogram.maximum == 2.0
    assert SMALLEST * RATIO ** BINS >= 1.0
    empty = LatencyHistogram()
    assert empty.percentile(99) is None
    assert empty.summary('x') == {'x_count': 0, 'x_p50': '', 'x_p99': '', 'x_max': ''}
    assert filled([4e-4]).summary('x') == {'x_count': 1, 'x_p50': '0.000400', 'x_p99': '0.000400',
                                           'x_max': '0.000400'}


def test_the_schedule_takes_a_step_at_its_due_time_despite_float_rounding():
    pacer = WallClockPacer(1e-3)
    pacer.restart(10.0, 7)
    assert ((10.0 + 1e-3) - 10.0) / 1e-3 < 1.0     # the rounding the tolerance is for
    assert [pacer.due(10.0 + k * 1e-3) for k in range(6)] == [7, 8, 9, 10, 11, 12]
    assert pacer.due(10.0 + 0.9e-3) == 7
    assert pacer.lateness(10.0035, 10) == pytest.approx(0.0005)


def test_a_slip_keeps_the_schedule_s_phase():
    pacer = WallClockPacer(1e-3)
    pacer.restart(10.0, 0)
    pacer.slip(10.0057, 1)                         # step 1 (due at 10.001) taken at 10.0057
    assert pacer.due_time(1) == pytest.approx(10.005) and pacer.due_time(2) == pytest.approx(10.006)
    assert pacer.due(10.0059) == 1 and pacer.due(10.006) == 2
