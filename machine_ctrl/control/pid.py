"""Parallel PID with a filtered derivative, the fast tool servo's position law (Ding thesis,
seed 003_edeaa855566124b7, Fig. 5-11 and Eq. 7-8, gains of section 7.5.3):

    u = K_p e_v + K_i integral(e_v) dt + K_d s/(T_f s + 1) e_v,   e_v = S (x_r - x)

e_v is the position error as the sensor's volts at the ADC (S: the sensor sensitivity, V/m),
u the DAC volts. The thesis's loop has no feed-forward: the law ignores v_r and a_r.

Discretization by the bilinear (Tustin) transform, each term on its own: the integral
term K_i T/2 (e_k + e_{k-1}) and the derivative filter
d_k = ((2 T_f - T) d_{k-1} + 2 K_d (e_k - e_{k-1})) / (2 T_f + T) (stable for any T_f > 0).
The integral is held as K_i times the integral, so that the integrator's output is the same
before and after a change of K_i.

Live gains: K_p, K_i and K_d may change between two steps. K_p and K_d move the command by
an amount proportional to the present error (the derivative term's state is its output, so
a new K_d scales only what follows); a new K_i acts on the future error only (bumpless).
T_f and S are fixed: T_f is the derivative filter's pole, S the sensor's calibration.
"""
from __future__ import annotations

from machine_ctrl.control.law import Parameter, gains_change_problem, retune_checked
from machine_ctrl.model.config import AxisConfig, PIDGains


class PIDController:
    parameters = (
        Parameter('proportional', 'V/V', 'K_p, Eq. (7-8)',
                  live='a step of (Delta K_p) e_v in the command, ~ the present error'),
        Parameter('integral', 'V/(V*s)', 'K_i, Eq. (7-8)',
                  live='bumpless: the integrator holds K_i * integral, a new K_i acts on new error only'),
        Parameter('derivative', 'V*s/V', 'K_d, Eq. (7-8)',
                  live='scales the derivative filter input from the next step, no jump in its state'),
        Parameter('derivative_filter', 's', 'T_f, derivative filter time constant, Eq. (7-8)'),
        Parameter('sensitivity', 'V/m (V/rad)', 'S, sensor volts per unit of position error'),
    )

    @classmethod
    def from_axis(cls, gains: PIDGains, axis: AxisConfig, period: float) -> PIDController:
        return cls(gains, period)

    def __init__(self, gains: PIDGains, period: float):
        self.period = period
        self._take(gains)
        self.reset()

    def _take(self, gains: PIDGains) -> None:
        self.gains = gains
        t, tf = self.period, gains.derivative_filter
        self._half_ki_t = 0.5 * gains.integral * self.period
        self._d_keep = (2.0 * tf - t) / (2.0 * tf + t)
        self._d_in = 2.0 * gains.derivative / (2.0 * tf + t)

    def retune_problem(self, gains: PIDGains) -> str | None:
        return gains_change_problem(self, gains)

    def retune(self, gains: PIDGains) -> None:
        """From the next step on (module doc)."""
        retune_checked(self, gains)
        self._take(gains)

    def reset(self) -> None:
        self.integral_term = 0.0
        self.derivative_term = 0.0
        self.last_error = None

    def step(self, x_r: float, v_r: float, a_r: float, x: float, v: float) -> float:
        e = self.gains.sensitivity * (x_r - x)
        last = e if self.last_error is None else self.last_error   # no derivative kick at the first step
        self.integral_term += self._half_ki_t * (e + last)
        self.derivative_term = self._d_keep * self.derivative_term + self._d_in * (e - last)
        self.last_error = e
        return self.gains.proportional * e + self.integral_term + self.derivative_term
