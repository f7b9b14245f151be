"""P position loop cascaded with a PI velocity loop (Yuen & Altintas CIRP 2016, seed 002,
Eq. 13, Table 1), the micromill's law "at the initial development of the machine":

    v_c = K_p (x_r - x),   u = K_v (v_c - v) + K_vi integral(v_c - v) dt

No velocity feed-forward (Eq. 13 has none); an optional LuGre friction feed-forward is added
by the servo (the paper's "feed-forward controller to compensate for the non-linear static
friction"). Gains in V*s/m and V/m (the paper's per-mm values times 1000).
"""
from __future__ import annotations

from machine_ctrl.control.law import Parameter
from machine_ctrl.model.config import AxisConfig, PPIGains


class PPIController:
    parameters = (
        Parameter('position_gain', '1/s', 'K_p, position loop gain, Eq. (13)'),
        Parameter('velocity_gain', 'V*s/m (V*s/rad)', 'K_v, velocity loop proportional gain, Eq. (13)'),
        Parameter('velocity_integral_gain', 'V/m (V/rad)', 'K_vi, velocity loop integral gain, Eq. (13)'),
    )

    @classmethod
    def from_axis(cls, gains: PPIGains, axis: AxisConfig, period: float) -> PPIController:
        return cls(gains, period)

    def __init__(self, gains: PPIGains, period: float):
        self.k_p, self.k_v, self.k_vi = gains.position_gain, gains.velocity_gain, gains.velocity_integral_gain
        self.period = period
        self.reset()

    def reset(self) -> None:
        self.integral = 0.0

    def step(self, x_r: float, v_r: float, a_r: float, x: float, v: float) -> float:
        velocity_error = self.k_p * (x_r - x) - v
        self.integral += velocity_error * self.period
        return self.k_v * velocity_error + self.k_vi * self.integral
