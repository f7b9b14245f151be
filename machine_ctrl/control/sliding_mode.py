"""Sliding-mode position control with an adaptive disturbance estimate (Yuen thesis
section 4.2.3, Eqs. 4.46-4.57), in the drive's command unit (V for the linear motors).

    sigma = (v_r - v) + lambda (x_r - x)                                  (4.47)
    u_smc = m_e [lambda (v_r - v) + a_r] + b_e v + d_hat + K_s sigma      (4.57)
    d_hat[k+1] = d_hat[k] + rho kappa sigma T_s                           (4.49)
    kappa = 0 when d_hat would leave [d-, d+] in the direction of sigma    (4.50)

with m_e = m / (K_a K_t), b_e = b / (K_a K_t) (Eq. 4.46). SI units: the thesis's K_s in
V s/mm and rho in V/mm are multiplied by 1000 in the machine config.

Live gains (:meth:`SlidingModeController.retune`): lambda, K_s and rho may change between
two steps. The law's only state is d_hat, an estimate of the disturbance that does not
depend on them; at the step of the change the command moves by (Delta K_s) sigma +
(Delta lambda) [m_e (v_r - v) + K_s (x_r - x)], i.e. in proportion to the tracking error. A new set
must keep the discrete loop well inside its stability limit: T (K_s / m_e + lambda) < 1, the
velocity-error pole 1 - T (K_s / m_e + lambda) of the sampled loop then stays in (0, 1)
(the shipped gains: 0.03-0.05 on the micromill, 0.22-0.63 on trt_5axis; with Sencer's printed
K_s, T K_s/m_e = 4.3, 2.9, 1.7 on x, y, z chattered at the +-10 V limit and 1.85 on c
diverged: trt_5axis.yaml). The disturbance bounds stay as built: d_hat may
already lie outside new ones.
"""
from __future__ import annotations

import dataclasses

from machine_ctrl.control.law import Parameter, gains_change_problem, retune_checked
from machine_ctrl.model.config import AxisConfig, SlidingModeGains


class SlidingModeController:
    parameters = (
        Parameter('bandwidth', '1/s', 'lambda, sliding-surface bandwidth, Eq. (4.47)',
                  live='a step of (Delta lambda) [m_e (v_r - v) + K_s (x_r - x)] in the command, ~ the tracking error'),
        Parameter('gain', 'V*s/m (V*s/rad)', 'K_s, gain on the sliding variable sigma, Eq. (4.57)',
                  live='a step of (Delta K_s) sigma in the command, ~ the tracking error'),
        Parameter('adaptation', 'V/m (V/rad)', 'rho, disturbance adaptation gain, Eq. (4.49)',
                  live='changes only the rate of the estimate d_hat, not its value'),
        Parameter('disturbance_bounds', 'V', '(d-, d+), range of the disturbance estimate, Eq. (4.50)'),
    )
    STABILITY = 1.0           # T (K_s / m_e + lambda) must stay below this (module docstring)

    @classmethod
    def from_axis(cls, gains: SlidingModeGains, axis: AxisConfig, period: float) -> SlidingModeController:
        """m_e, b_e from the axis's drive (Eq. 4.46)."""
        drive = axis.drive
        if drive.mass is None or drive.damping is None:
            raise ValueError(f'axis {axis.name}: sliding_mode needs the drive\'s mass and damping '
                             f'(a {drive.type} drive has none)')
        return cls(gains, drive.mass / drive.gain, drive.damping / drive.gain, period)

    def __init__(self, gains: SlidingModeGains, equivalent_mass: float, equivalent_damping: float,
                 period: float):
        self.gains = gains
        self.lam, self.k_s, self.rho = gains.bandwidth, gains.gain, gains.adaptation
        self.d_low, self.d_high = gains.disturbance_bounds
        self.m_e, self.b_e, self.period = equivalent_mass, equivalent_damping, period
        self.reset()

    def retune_problem(self, gains: SlidingModeGains) -> str | None:
        problem = gains_change_problem(self, gains)
        if problem is None and gains != self.gains:
            margin = self.period * (gains.gain / self.m_e + gains.bandwidth)
            if margin >= self.STABILITY:
                changed = [f.name for f in dataclasses.fields(gains)
                           if getattr(gains, f.name) != getattr(self.gains, f.name)]
                problem = (f'{", ".join(changed)}: T (K_s / m_e + lambda) = {margin:.3g} must be < {self.STABILITY:g} '
                           f'(the sampled loop would oscillate or diverge; K_s {gains.gain:g}, '
                           f'lambda {gains.bandwidth:g}, m_e {self.m_e:.4g}, T {self.period:g})')
        return problem

    def retune(self, gains: SlidingModeGains) -> None:
        """From the next step on (d_hat kept)."""
        retune_checked(self, gains)
        self.gains = gains
        self.lam, self.k_s, self.rho = gains.bandwidth, gains.gain, gains.adaptation

    def reset(self) -> None:
        self.d_hat = 0.0

    @property
    def design_bandwidth(self) -> float:
        """lambda, rad/s: "analogous to the bandwidth of the sliding mode controller" (thesis
        text at Eq. 4.47)."""
        return self.lam

    def step(self, x_r: float, v_r: float, a_r: float, x: float, v: float, acc: float = 0.0) -> float:
        velocity_error = v_r - v
        sigma = velocity_error + self.lam * (x_r - x)
        u = self.m_e * (self.lam * velocity_error + a_r) + self.b_e * v + self.d_hat + self.k_s * sigma
        d_hat = self.d_hat
        if not ((d_hat <= self.d_low and sigma <= 0.0) or (d_hat >= self.d_high and sigma >= 0.0)):
            self.d_hat = d_hat + self.rho * sigma * self.period
        return u
