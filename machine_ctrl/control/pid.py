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

With the cascade acceleration loop of Fig. 7-6 / Eq. (7-7) (acceleration_gain K_a > 0):

    u = PID - K_a H_a(s) H_acc acc,   H_acc acc = accelerometer_sensitivity * acc

acc the accelerometer's reading (m/s^2), H_a an optional first-order low-pass of corner
acceleration_filter (rad/s; 0: H_a = 1), Tustin like the derivative filter. The law then
needs an accelerometer on its axis (``plant.accelerometer``) and says so
(``uses_acceleration``).

Live gains: K_p, K_i and K_d may change between two steps. K_p and K_d move the command by
an amount proportional to the present error (the derivative term's state is its output, so
a new K_d scales only what follows); a new K_i acts on the future error only (bumpless).
T_f and S are fixed: T_f is the derivative filter's pole, S the sensor's calibration; so
are K_a, H_acc and H_a (section 7.4.1 changes K_a together with the PID gains; a servo
node subscribes the accelerometer readings when its law starts with K_a > 0, so a running
loop gains or loses its acceleration loop only as a new law).
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
        Parameter('acceleration_gain', 'V/V', 'K_a, acceleration loop gain, Eq. (7-7)'),
        Parameter('accelerometer_sensitivity', 'V/(m/s^2)', 'H_acc at DC, accelerometer volts per m/s^2, Fig. 7-6'),
        Parameter('acceleration_filter', 'rad/s', 'corner of the first-order H_a, Fig. 7-6 (0: H_a = 1)'),
    )

    @classmethod
    def from_axis(cls, gains: PIDGains, axis: AxisConfig, period: float) -> PIDController:
        if gains.acceleration_gain > 0.0:
            if axis.plant is None or axis.plant.accelerometer is None:
                raise ValueError(f'axis {axis.name}: acceleration_gain > 0 needs an accelerometer on the axis '
                                 '(plant.accelerometer in the machine config)')
            if gains.accelerometer_sensitivity <= 0.0:
                raise ValueError(f'axis {axis.name}: acceleration_gain > 0 needs accelerometer_sensitivity > 0')
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
        self.uses_acceleration = gains.acceleration_gain > 0.0
        self._ka_volts = gains.acceleration_gain * gains.accelerometer_sensitivity
        wa = gains.acceleration_filter                 # H_a = wa / (s + wa), Tustin
        self._a_keep = (2.0 - wa * t) / (2.0 + wa * t) if wa > 0.0 else 0.0
        self._a_in = wa * t / (2.0 + wa * t) if wa > 0.0 else 0.0

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
        self.acceleration_term = 0.0                   # H_a of the last reading
        self.last_acceleration = None

    def step(self, x_r: float, v_r: float, a_r: float, x: float, v: float, acc: float = 0.0) -> float:
        e = self.gains.sensitivity * (x_r - x)
        last = e if self.last_error is None else self.last_error   # no derivative kick at the first step
        self.integral_term += self._half_ki_t * (e + last)
        self.derivative_term = self._d_keep * self.derivative_term + self._d_in * (e - last)
        self.last_error = e
        u = self.gains.proportional * e + self.integral_term + self.derivative_term
        if not self.uses_acceleration:
            return u
        if self._a_in:                                 # H_a, from its first reading at rest (no step)
            if self.last_acceleration is None:
                self.acceleration_term = acc
            else:
                self.acceleration_term = self._a_keep * self.acceleration_term + self._a_in * (acc + self.last_acceleration)
            self.last_acceleration = acc
            acc = self.acceleration_term
        return u - self._ka_volts * acc
