"""P position loop cascaded with a PI velocity loop (Yuen & Altintas CIRP 2016, seed 002,
Eq. 13, Table 1), the micromill's law "at the initial development of the machine":

    v_c = K_p (x_r - x),   u = K_v (v_c - v) + K_vi integral(v_c - v) dt

No velocity feed-forward (Eq. 13 has none); an optional LuGre friction feed-forward is added
by the servo (the paper's "feed-forward controller to compensate for the non-linear static
friction"). Gains in V*s/m and V/m (the paper's per-mm values times 1000).

Live gains (:meth:`PPIController.retune`): all three may change between two steps. K_p and
K_v move the command by an amount proportional to the tracking error; a new K_vi rescales
the integral so that K_vi * integral, the force the integrator holds (friction, load), is
the same before and after (bumpless). Switching the integral action on or off (K_vi to or
from 0) cannot be bumpless and is refused while running.
"""
from __future__ import annotations

from machine_ctrl.control.law import Parameter, gains_change_problem, retune_checked
from machine_ctrl.model.config import AxisConfig, PPIGains


class PPIController:
    parameters = (
        Parameter('position_gain', '1/s', 'K_p, position loop gain, Eq. (13)',
                  live='a step of K_v (Delta K_p) (x_r - x) in the command, ~ the tracking error'),
        Parameter('velocity_gain', 'V*s/m (V*s/rad)', 'K_v, velocity loop proportional gain, Eq. (13)',
                  live='a step of (Delta K_v) (v_c - v) in the command, ~ the velocity error'),
        Parameter('velocity_integral_gain', 'V/m (V/rad)', 'K_vi, velocity loop integral gain, Eq. (13)',
                  live='bumpless: the integral is rescaled so that K_vi * integral is kept (not to or from 0)'),
    )

    @classmethod
    def from_axis(cls, gains: PPIGains, axis: AxisConfig, period: float) -> PPIController:
        return cls(gains, period)

    def __init__(self, gains: PPIGains, period: float):
        self.gains = gains
        self.k_p, self.k_v, self.k_vi = gains.position_gain, gains.velocity_gain, gains.velocity_integral_gain
        self.period = period
        self.reset()

    def retune_problem(self, gains: PPIGains) -> str | None:
        problem = gains_change_problem(self, gains)
        if problem is None and (gains.velocity_integral_gain == 0.0) != (self.k_vi == 0.0):
            problem = (f'velocity_integral_gain: switching the integral action {"off" if self.k_vi else "on"} '
                       f'is not bumpless (from {self.k_vi:g} to {gains.velocity_integral_gain:g}); set it at start')
        return problem

    def retune(self, gains: PPIGains) -> None:
        """From the next step on; the integrator's output K_vi * integral is kept."""
        retune_checked(self, gains)
        if gains.velocity_integral_gain != self.k_vi:
            self.integral *= self.k_vi / gains.velocity_integral_gain
        self.gains = gains
        self.k_p, self.k_v, self.k_vi = gains.position_gain, gains.velocity_gain, gains.velocity_integral_gain

    def reset(self) -> None:
        self.integral = 0.0

    def step(self, x_r: float, v_r: float, a_r: float, x: float, v: float, acc: float = 0.0) -> float:
        velocity_error = self.k_p * (x_r - x) - v
        self.integral += velocity_error * self.period
        return self.k_v * velocity_error + self.k_vi * self.integral
