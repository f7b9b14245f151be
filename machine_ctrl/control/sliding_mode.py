"""Sliding-mode position control with an adaptive disturbance estimate (Yuen thesis
section 4.2.3, Eqs. 4.46-4.57), in the drive's command unit (V for the linear motors).

    sigma = (v_r - v) + lambda (x_r - x)                                  (4.47)
    u_smc = m_e [lambda (v_r - v) + a_r] + b_e v + d_hat + K_s sigma      (4.57)
    d_hat[k+1] = d_hat[k] + rho kappa sigma T_s                           (4.49)
    kappa = 0 when d_hat would leave [d-, d+] in the direction of sigma    (4.50)

with m_e = m / (K_a K_t), b_e = b / (K_a K_t) (Eq. 4.46). SI units: the thesis's K_s in
V s/mm and rho in V/mm are multiplied by 1000 in the machine config.
"""
from __future__ import annotations

from machine_ctrl.control.law import Parameter
from machine_ctrl.model.config import AxisConfig, SlidingModeGains


class SlidingModeController:
    parameters = (
        Parameter('bandwidth', '1/s', 'lambda, sliding-surface bandwidth, Eq. (4.47)'),
        Parameter('gain', 'V*s/m (V*s/rad)', 'K_s, gain on the sliding variable sigma, Eq. (4.57)'),
        Parameter('adaptation', 'V/m (V/rad)', 'rho, disturbance adaptation gain, Eq. (4.49)'),
        Parameter('disturbance_bounds', 'V', '(d-, d+), range of the disturbance estimate, Eq. (4.50)'),
    )

    @classmethod
    def from_axis(cls, gains: SlidingModeGains, axis: AxisConfig, period: float) -> SlidingModeController:
        """m_e, b_e from the axis's drive (Eq. 4.46)."""
        drive = axis.drive
        return cls(gains, drive.mass / drive.gain, drive.damping / drive.gain, period)

    def __init__(self, gains: SlidingModeGains, equivalent_mass: float, equivalent_damping: float,
                 period: float):
        self.lam, self.k_s, self.rho = gains.bandwidth, gains.gain, gains.adaptation
        self.d_low, self.d_high = gains.disturbance_bounds
        self.m_e, self.b_e, self.period = equivalent_mass, equivalent_damping, period
        self.reset()

    def reset(self) -> None:
        self.d_hat = 0.0

    def step(self, x_r: float, v_r: float, a_r: float, x: float, v: float) -> float:
        velocity_error = v_r - v
        sigma = velocity_error + self.lam * (x_r - x)
        u = self.m_e * (self.lam * velocity_error + a_r) + self.b_e * v + self.d_hat + self.k_s * sigma
        d_hat = self.d_hat
        if not ((d_hat <= self.d_low and sigma <= 0.0) or (d_hat >= self.d_high and sigma >= 0.0)):
            self.d_hat = d_hat + self.rho * sigma * self.period
        return u
