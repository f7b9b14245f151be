"""Lead-lag + integrator + notch position control of the rotary table (Yuen thesis
section 4.3, Eqs. 4.73-4.76, Table 4.4):

    C(s) = K_f (1 + alpha T s)/(1 + T s) * (1 + K_i/s) * N_a(s) N_b(s)

acting on the position error, output in the table's command unit (N or N*m).

Discretization: each section separately by the bilinear (Tustin) transform with frequency
pre-warping — the lead-lag at its centre frequency 1/(T sqrt(alpha)) (the designed
crossover omega_m, where its phase lead must survive), each notch at its own omega (so the
notch stays on the resonance), the integrator without pre-warping (its corner is far below
Nyquist). At 10 kHz the lead-lag section is then exact at omega_m; with the integrator and
the notches |C| is off by <= 0.3 % and the phase by <= 0.1 deg there (the micromill's axes).

No live gains: every gain is folded into the coefficients of the filter sections, whose
states belong to those coefficients; new coefficients on old states would be a jump in the
table's command (retune accepts only the gains in use).
"""
from __future__ import annotations

import math

from machine_ctrl.control.filters import tustin
from machine_ctrl.control.law import Parameter, gains_change_problem, retune_checked
from machine_ctrl.model.config import AxisConfig, LeadLagGains


class LeadLagController:
    parameters = (                      # the symbols of C(s) above
        Parameter('gain', 'command unit/m (/rad)', 'K_f, lead-lag gain'),
        Parameter('alpha', '1', 'alpha, lead ratio (phase lead at 1/(T sqrt(alpha)))'),
        Parameter('time_constant', 's', 'T, lead-lag time constant'),
        Parameter('integral', 'rad/s', 'K_i, integrator corner (0: no integrator)'),
        Parameter('notches', 'rad/s, 1, 1', 'notches N(s): omega, zeta_num, zeta_den each, Eq. (4.76)'),
    )

    error_feedback = True               # C(s) acts on x_r - x alone (module docstring)

    @classmethod
    def from_axis(cls, gains: LeadLagGains, axis: AxisConfig, period: float) -> LeadLagController:
        return cls(gains, period)

    @property
    def design_bandwidth(self) -> float:
        """omega_m = 1/(T sqrt(alpha)), the designed open-loop crossover, rad/s (Eq. 4.74)."""
        return 1.0 / (self.gains.time_constant * math.sqrt(self.gains.alpha))

    def __init__(self, gains: LeadLagGains, period: float):
        self.gains = gains
        k, alpha, t = gains.gain, gains.alpha, gains.time_constant
        sections = [tustin([k * alpha * t, k], [t, 1.0], period, prewarp=1.0 / (t * math.sqrt(alpha)))]
        if gains.integral > 0.0:
            sections.append(tustin([1.0, gains.integral], [1.0, 0.0], period))
        for notch in gains.notches:
            w = notch.omega
            sections.append(tustin([1.0, 2.0 * notch.zeta_num * w, w * w],
                                   [1.0, 2.0 * notch.zeta_den * w, w * w], period, prewarp=w))
        self.sections = sections

    def retune_problem(self, gains: LeadLagGains) -> str | None:
        return gains_change_problem(self, gains)

    def retune(self, gains: LeadLagGains) -> None:
        retune_checked(self, gains)

    def reset(self) -> None:
        for section in self.sections:
            section.reset()

    def step(self, x_r: float, v_r: float, a_r: float, x: float, v: float, acc: float = 0.0) -> float:
        y = x_r - x
        for section in self.sections:
            y = section.step(y)
        return y
