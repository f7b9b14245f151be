"""Shared test check: sampled axis positions, differenced at the control period (what a
servo sees), stay within the machine's velocity, acceleration and jerk limits, up to the
float64 error of the positions themselves (rounding_error)."""
import numpy as np

# Float64 error of one sampled position, in ulp(|q|): rounding the value alone gives 1/2;
# Ruckig evaluates each phase from its rounded start state (p_k + t (v_k + t (a_k/2 + t j_k/6))),
# which the 7.4 rad return of fts_lathe's c at 5 µs shows at about 0.7 (its third difference
# reads 2.1 % over the jerk limit while its analytic acceleration steps stay within 1 + 2e-11).
SAMPLE_ULPS = 2.0
# A machine standing still moves by its noise-driven jitter only: below these, in m and rad
# (test_robustness: the micromill table's tilt jitter reaches ~20 µrad peak to peak under the
# assumed table force noise of its machine YAML; a bad goal would move far more)
LINEAR_STILL, ROTARY_STILL = 1e-6, 100e-6


def rounding_error(order: int, magnitude, period: float, ulps: float = SAMPLE_ULPS):
    """Bound on the error that `ulps` x ulp(|q|) on each position up to |q| = `magnitude` (one
    per axis, or an array) puts into the `order`-th difference over period^order: the n-th
    difference sums 2^n positions, 2^n ulps ulp / T^n. At the micromill's strokes and 100 µs
    it is ~2e-6 of a limit at most; at a spindle's 7 rad and 5 µs about 6 % of its jerk, so
    such checks go with :func:`assert_reference_within_limits`."""
    return 2.0 ** order * ulps * np.spacing(np.abs(magnitude)) / period ** order


def assert_within_limits(machine, positions, tolerance=1.001):
    t = machine.control_period
    magnitude = np.abs(positions).max(axis=0)
    for order, name in ((1, 'velocity'), (2, 'acceleration'), (3, 'jerk')):
        limit = np.array([getattr(a.limits, name) for a in machine.axes])
        peak = np.abs(np.diff(positions, order, axis=0)).max(axis=0) / t**order
        bound = tolerance * limit + rounding_error(order, magnitude, t)
        assert (peak <= bound).all(), f'{name}: peak / limit {peak / limit}'


def assert_reference_within_limits(machine, reference, tolerance=1.001):
    """The reference's own velocity and acceleration (Ruckig's, not differenced positions)
    and the jerk from the acceleration's steps within the limits: no position rounding in
    them, so they stay sharp where the positions are large (a spindle turns after turns)."""
    t = machine.control_period
    for name, values in (('velocity', reference.velocity), ('acceleration', reference.acceleration),
                         ('jerk', np.diff(reference.acceleration, axis=0) / t)):
        limit = np.array([getattr(a.limits, name) for a in machine.axes])
        peak = np.abs(values).max(axis=0)
        assert (peak <= tolerance * limit).all(), f'{name}: peak / limit {peak / limit}'
