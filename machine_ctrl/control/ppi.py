"""P position loop cascaded with a PI velocity loop (Yuen & Altintas CIRP 2016, seed 002,
Eq. 13, Table 1), the micromill's law "at the initial development of the machine":

    v_c = K_p (x_r - x),   u = K_v (v_c - v) + K_vi integral(v_c - v) dt

No velocity feed-forward (Eq. 13 has none); an optional LuGre friction feed-forward is added
by the servo (the paper's "feed-forward controller to compensate for the non-linear static
friction"). Gains in V*s/m and V/m (the paper's per-mm values times 1000).
"""
from __future__ import annotations

from machine_ctrl.model.config import PPIGains


class PPIController:
    def __init__(self, gains: PPIGains, period: float):
        self.k_p, self.k_v, self.k_vi = gains.position_gain, gains.velocity_gain, gains.velocity_integral_gain
        self.period = period
        self.integral = 0.0

    def update(self, x_r: float, v_r: float, a_r: float, x: float, v: float) -> float:
        velocity_error = self.k_p * (x_r - x) - v
        self.integral += velocity_error * self.period
        return self.k_v * velocity_error + self.k_vi * self.integral
