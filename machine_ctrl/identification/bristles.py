"""The LuGre bristles of a feed drive, sigma0 and sigma1 (Yuen thesis section 4.2.4, Eqs.
4.58, 4.62), from the presliding response to force steps below breakaway. Plain numeric
functions (numpy, scipy); no ROS, no simulator.

Below breakaway the guideway does not slide: the carriage moves by the bristles' deflection
alone, micrometres, against their stiffness sigma0 and damping sigma1:

    m x'' = F - sigma0 z - sigma1 z' - b x',   z' = x' - sigma0 |x'| z / g(x')   (Eqs. 4.58, 4.62)

with g the friction curve (Eq. 4.41) times the friction's level where the carriage stands.
Everything but sigma0 and sigma1 comes from the identification before (m and b from the
rigid-body and steady fits, g from the Stribeck fit and the variation along the stroke), so
this is a grey-box fit of the thesis's own model: the response to each step is simulated
(scipy.integrate.solve_ivp, the force held over each period) and sigma0, sigma1 are the
least-squares fit of the simulated to the measured positions (scipy.optimize.least_squares,
in log-parameters: both positive), with an offset per step: the rest position each step is
measured from is one encoder reading, up to half a count off the carriage's.

From rest with no force applied the bristles hold no deflection (sigma0 z balances the
applied force, zero), so each step starts at z = 0 whatever the carriage did before.

Why steps of about half the breakaway force: the deflection is then tens of encoder counts
(x_ss = -(g/sigma0) ln(1 - F/g): 2.8 um for F = g/2 on the micromill's x_c), and the term
sigma0 |x'| z / g that makes the bristles stiffen as they approach g/sigma0 is in the model,
so no small-signal approximation biases sigma0. sigma1 is seen in the transient: with the
thesis's critical damping (Eq. 4.65) the step settles in a few ms without overshoot.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from machine_ctrl.identification.status import FitStatus


@dataclass(frozen=True)
class BristleFit:
    status: FitStatus
    reason: str = ''
    sigma0: float = math.nan          # N/m
    sigma1: float = math.nan          # N s/m
    residual_rms: float = math.nan    # m, measured - simulated positions
    steps: int = 0                    # force steps used


@dataclass(frozen=True)
class PreslidingStep:
    """One step from rest: the force held from the step on (N), the encoder positions at the
    following periods' starts relative to the rest position (m; the first is the step's
    instant), and g, the friction curve there (N as a function of the velocity, m/s)."""
    force: float
    position: np.ndarray
    curve: Callable[[float], float]


def simulate(step: PreslidingStep, period: float, mass: float, viscous: float, sigma0: float,
             sigma1: float) -> np.ndarray:
    """The positions of the model (module docstring) at each period's start, from rest."""
    from scipy.integrate import solve_ivp

    def rates(_, state):
        x, v, z = state
        dz = v - sigma0 * abs(v) * z / step.curve(v)
        return (v, (step.force - sigma0 * z - sigma1 * dz - viscous * v) / mass, dz)
    times = np.arange(len(step.position)) * period
    return solve_ivp(rates, (0.0, times[-1]), np.zeros(3), method='LSODA', t_eval=times, rtol=1e-9,
                     atol=1e-14).y[0]


def fit_bristles(steps: list[PreslidingStep], period: float, mass: float, viscous: float,
                 start: tuple[float, float]) -> BristleFit:
    """sigma0 and sigma1 from `steps` (each from rest; module docstring), `mass` (kg) and
    `viscous` (N s/m) known, from `start` (sigma0, sigma1)."""
    if not steps:
        return BristleFit(FitStatus.REFUSED, 'no presliding step')
    moved = [s for s in steps if np.ptp(s.position) > 0.0]
    if len(moved) < len(steps):
        return BristleFit(FitStatus.REFUSED, f'{len(steps) - len(moved)} of {len(steps)} steps moved no encoder '
                                                 'count: a larger force is needed')
    if not (mass > 0 and viscous >= 0 and all(v > 0 for v in start)):
        return BristleFit(FitStatus.REFUSED, f'mass {mass!r}, viscous {viscous!r}, start {start!r}: need m > 0, '
                                                 'b >= 0, a positive start')
    from scipy.optimize import least_squares
    measured = np.concatenate([s.position for s in steps])
    scale = float(np.abs(measured).max())           # residuals relative to the largest deflection
    lengths = [len(s.position) for s in steps]

    def residual(theta):                            # log sigma0, log sigma1, each step's rest offset / scale
        sigma0, sigma1 = np.exp(theta[:2])
        offsets = np.repeat(theta[2:], lengths)
        simulated = np.concatenate([simulate(s, period, mass, viscous, sigma0, sigma1) for s in steps])
        return (simulated - measured) / scale + offsets
    solution = least_squares(residual, np.concatenate((np.log(start), np.zeros(len(steps)))), method='trf',
                             diff_step=1e-4)
    if not solution.success:
        return BristleFit(FitStatus.REFUSED, f'the fit did not converge: {solution.message}')
    sigma0, sigma1 = (float(v) for v in np.exp(solution.x[:2]))
    return BristleFit(FitStatus.OK, '', sigma0, sigma1, scale * float(np.sqrt(np.mean(solution.fun ** 2))),
                      len(steps))
