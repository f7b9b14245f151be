"""Servo laws against their equations, written out here independently."""
import math

import numpy as np
import pytest

from machine_ctrl.model.config import LeadLagGains, NotchConfig, PPIGains, SlidingModeGains
from machine_ctrl.control.lead_lag import LeadLagController
from machine_ctrl.control.lugre import LuGreFeedforward, StribeckCurve
from machine_ctrl.control.ppi import PPIController
from machine_ctrl.control.sliding_mode import SlidingModeController

T = 1e-4


def test_sliding_mode_law_and_adaptation():
    gains = SlidingModeGains(bandwidth=200.0, gain=50.0, adaptation=5e4, disturbance_bounds=(-1.5, 1.5))
    smc = SlidingModeController(gains, equivalent_mass=0.4667, equivalent_damping=0.55, period=T)
    x_r, v_r, a_r, x, v = 1e-3, 0.01, 0.2, 0.9e-3, 0.008
    sigma = (v_r - v) + 200.0 * (x_r - x)                                        # (4.47)
    expected = 0.4667 * (200.0 * (v_r - v) + a_r) + 0.55 * v + 0.0 + 50.0 * sigma  # (4.57), d_hat = 0
    assert smc.step(x_r, v_r, a_r, x, v) == pytest.approx(expected, rel=1e-12)
    assert smc.d_hat == pytest.approx(5e4 * sigma * T)                           # (4.49)


def test_sliding_mode_estimate_stops_at_its_bounds():
    gains = SlidingModeGains(bandwidth=200.0, gain=50.0, adaptation=5e4, disturbance_bounds=(-0.1, 0.1))
    smc = SlidingModeController(gains, 0.4667, 0.55, T)
    for _ in range(1000):
        smc.step(1e-3, 0.0, 0.0, 0.0, 0.0)                                     # sigma > 0 always
    assert 0.1 <= smc.d_hat < 0.1 + 5e4 * 0.2 * T                                # (4.50): kappa = 0 above d+
    held = smc.d_hat
    smc.step(1e-3, 0.0, 0.0, 0.0, 0.0)
    assert smc.d_hat == held
    smc.step(-1e-3, 0.0, 0.0, 0.0, 0.0)                                        # sigma < 0: may decrease
    assert smc.d_hat < held


def test_lugre_feedforward_reaches_the_friction_curve():
    """Asymmetric (Eq. 4.41 by direction), so that a direction mix-up shows; the steady
    force written out by hand."""
    curve = StribeckCurve((29.15, 20.0), (26.67, 18.0), (0.0243, 0.01), (0.0243, 0.02))
    ff = LuGreFeedforward(curve, 9e5, 1500.0, gain=45.4, period=T)
    for _ in range(5000):
        u = ff.step(0.01)
    assert u * 45.4 == pytest.approx(26.67 + (29.15 - 26.67) * math.exp(-0.01 / 0.0243), rel=1e-6)
    for _ in range(5000):
        u = ff.step(-0.01)
    assert u * 45.4 == pytest.approx(-(20.0 * math.exp(-1.0) + 18.0 * (1.0 - math.exp(-0.5))), rel=1e-6)


def test_ppi_is_p_cascaded_with_pi():
    ppi = PPIController(PPIGains(position_gain=275.8, velocity_gain=175.0, velocity_integral_gain=61600.0), T)
    e_v = 275.8 * 2e-6 - 0.001
    assert ppi.step(2e-6, 0.0, 0.0, 0.0, 0.001) == pytest.approx(175.0 * e_v + 61600.0 * e_v * T)


def discrete_response(controller, frequencies):
    """Frequency response of the controller measured by driving it with sinusoids."""
    out = []
    for f in frequencies:
        n = int(round(40 / (f * T)))
        t = np.arange(n) * T
        y = np.array([controller.step(math.sin(2 * math.pi * f * ti), 0, 0, 0, 0) for ti in t])
        tail = slice(n // 2, None)
        out.append(2 * np.mean(y[tail] * np.exp(-2j * math.pi * f * t[tail])))
    return np.array(out) / -1j   # input was sin = Im(e^{jwt}): divide by the phasor of sin


def continuous_response(gains, frequencies):
    s = 2j * math.pi * np.asarray(frequencies)
    c = gains.gain * (1 + gains.alpha * gains.time_constant * s) / (1 + gains.time_constant * s)
    c *= 1 + gains.integral / s
    for n in gains.notches:
        c *= (s**2 + 2 * n.zeta_num * n.omega * s + n.omega**2) / (s**2 + 2 * n.zeta_den * n.omega * s + n.omega**2)
    return c


def test_lead_lag_discretization_keeps_the_designed_crossover():
    """Tustin pre-warped at omega_m: at 250 Hz the discrete controller has the continuous
    controller's phase and gain (Eqs. 4.73-4.75, Table 4.4 x_f)."""
    gains = LeadLagGains(gain=5.95e5, alpha=131.0, time_constant=5.57e-5, integral=157.1)
    f_m = 1 / (5.57e-5 * math.sqrt(131.0)) / (2 * math.pi)
    fresh = [LeadLagController(gains, T) for _ in range(1)]
    measured = discrete_response(fresh[0], [f_m])[0]
    ideal = continuous_response(gains, [f_m])[0]
    assert abs(measured) == pytest.approx(abs(ideal), rel=2e-3)
    assert math.degrees(np.angle(measured / ideal)) == pytest.approx(0.0, abs=0.2)


def test_notch_sits_on_its_frequency():
    notch = NotchConfig(omega=1992.0, zeta_num=0.02, zeta_den=0.3)
    gains = LeadLagGains(gain=1.0, alpha=1.0, time_constant=1e-3, integral=0.0, notches=(notch,))
    f = 1992.0 / (2 * math.pi)
    depth = abs(discrete_response(LeadLagController(gains, T), [f])[0])
    assert depth == pytest.approx(0.02 / 0.3, rel=0.02)              # |N(j omega)| = zeta_num / zeta_den


def test_bilinear_is_tustins_substitution_worked_by_hand():
    """filters.bilinear against the substitution s = 2 fs (z - 1)/(z + 1) multiplied out by
    hand for a second-order section (coefficients of z^2, z, 1), and against
    scipy.signal.bilinear where scipy does not drop a small leading coefficient."""
    from scipy import signal
    from machine_ctrl.control.filters import bilinear
    n, d, fs = (2.0, 3.0e3, 5.0e6), (1.0, 4.0e2, 9.0e6), 2.0e4
    k = 2.0 * fs

    def by_hand(c):
        return np.array([c[0] * k * k + c[1] * k + c[2], 2.0 * (c[2] - c[0] * k * k), c[0] * k * k - c[1] * k + c[2]])
    b, a = bilinear(n, d, fs)
    np.testing.assert_allclose(b, by_hand(n) / by_hand(d)[0], rtol=1e-12)
    np.testing.assert_allclose(a, by_hand(d) / by_hand(d)[0], rtol=1e-12)
    for num, den in ((n, d), ((1.0, 50.0), (1.0, 500.0)), ((7.0,), (1.0, 30.0, 1e4))):
        expected = signal.bilinear(num, den, fs)
        assert all(np.array_equal(x, y) for x, y in zip(bilinear(num, den, fs), expected))
    # scipy takes a numerator of 1e-15 s for no numerator at all; here it stays
    assert bilinear((1e-15, 0.0), (1.0, 1.0), fs)[0][0] > 0.0
    with pytest.raises(ValueError, match='vanishes at s = 2 fs'):
        bilinear((1.0,), (1.0, -k), fs)
