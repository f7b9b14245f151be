"""Deflection compensation of an industrial robot during milling (Sörnmo, seed
004_33b29b0855b96c5a, Ch. 4, §4.2, Figs. 4.1-4.2): the robot's path is adjusted on line so
that its arm-side position z_a follows the desired z_d despite the process force.

* Stiffness model (§4.2, Eq. 4.1, f = K_f x_p): a table of stiffness measured at points of
  the workspace, linearly interpolated between them (held at the end values beyond the
  table), looked up at the robot's own measured position in the workspace (§4.2's z_m; in
  the one-direction experiment the coordinate along the feed, which the deflection, normal
  to the feed, does not change).
* Force feedback (FF, Fig. 4.1): the measured force f gives the deflection e_z = f / K(z_m)
  in the direction of the force; the arm-side position is estimated as z_m + e_z and the
  error fed to C(s) is z_d - (z_m + e_z), so the compensation acts opposite to the force.
  (The seed feeds "the deflection" to C(s); the velocity reference is integrated into the
  position reference, so the loop needs the deflection minus the correction already made,
  which is what z_d - z_m adds: the integrator then stops where the correction equals -e_z.)
* Position feedback (PF, Fig. 4.2): the error is z_d - z_a with z_a from the tracker.
* C(s) = k_c w_c / (s + w_c), "a low-pass filtered proportional controller" (§4.2), its
  output a velocity reference v_r, integrated into the position reference; both are sent
  to the robot. Discretized at the ORCA rate (250 Hz, §4.3) by the bilinear transform
  pre-warped at w_c (control/filters.py), so DC gain and cut-off are exact; the integral
  by backward Euler, q_k = q_{k-1} + h v_k.

The values of C(s) are not printed; both are assumed from the seed's rules:

* cut-off (:data:`CUTOFF`): "a magnitude lower than the bandwidth of the robot, in order not
  to act on high-frequency errors that the robot is unable to compensate for, because of its
  limited structural bandwidth": the structure's 9 Hz eigenfrequency (§2.6, Fig. 2.15) / 10.
* gain (:data:`GAIN`): "a low value in order not to amplify noise": k_c = w_c / 4, the
  largest gain at which the loop k_c w_c / (s (s + w_c)) (robot ~1 at these frequencies) has
  no overshoot (a double pole at -w_c/2; 76 deg phase margin).

:func:`design` checks a configuration and answers with a status and a reason, never an
exception; :class:`DeflectionCompensator` runs a design, one step per ORCA period.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from machine_ctrl.control.filters import Biquad, tustin
from machine_ctrl.model.numeric import all_finite

PERIOD = 1.0 / 250.0                 # s, ORCA runs at 250 Hz, seed §4.3
EIGENFREQUENCY = 9.0                 # Hz, the REIS RV40's first eigenfrequency (§2.6, Fig. 2.15), assumed for Ch. 4's IRB 2400
CUTOFF = EIGENFREQUENCY / 10.0       # Hz, assumed: "a magnitude lower than the bandwidth" (module doc)
GAIN = 2.0 * math.pi * CUTOFF / 4.0  # 1/s, assumed: "a low value": no overshoot (module doc)


class Status(enum.Enum):
    OK = 'ok'
    FAILED = 'failed'


@dataclass(frozen=True)
class DeflectionConfig:
    """C(s) = gain 2 pi cutoff / (s + 2 pi cutoff) at sample `period` (module doc)."""
    gain: float = GAIN           # 1/s: velocity reference per metre of error at DC
    cutoff: float = CUTOFF       # Hz
    period: float = PERIOD       # s


@dataclass(frozen=True)
class StiffnessTable:
    """Stiffness (N/m) measured at increasing positions (m) of the workspace (§4.2)."""
    positions: tuple[float, ...]
    stiffness: tuple[float, ...]

    def at(self, position: float) -> float:
        """K at `position`: linear between the table's points, the end value beyond them."""
        return float(np.interp(position, self.positions, self.stiffness))


@dataclass(frozen=True)
class DeflectionDesign:
    config: DeflectionConfig
    table: StiffnessTable | None     # needed by force feedback only

    def low_pass(self) -> Biquad:
        """C(s) of the module doc as a fresh discrete section (Tustin, pre-warped at the cut-off)."""
        c = self.config
        w = 2.0 * math.pi * c.cutoff
        return tustin([c.gain * w], [1.0, w], c.period, prewarp=w)


@dataclass(frozen=True)
class DeflectionResult:
    status: Status
    reason: str
    design: DeflectionDesign | None = None

    @property
    def ok(self) -> bool:
        return self.status is Status.OK


def _refusal(config: DeflectionConfig, table: StiffnessTable | None) -> str:
    """Why `config` and `table` cannot make a compensator ('' when they can)."""
    values = (config.gain, config.cutoff, config.period)
    if not all_finite(values):
        return f'gain, cut-off and period must be finite numbers, got {values}'
    if config.period <= 0.0:
        return f'the period must be positive, got {config.period} s'
    if config.gain <= 0.0:
        return f'the gain must be positive (a velocity towards the error), got {config.gain} 1/s'
    nyquist = 0.5 / config.period
    if not 0.0 < config.cutoff < nyquist:
        return f'the cut-off must lie within (0, {nyquist:g}) Hz, the Nyquist band, got {config.cutoff} Hz'
    if table is None:
        return ''
    positions, stiffness = tuple(table.positions), tuple(table.stiffness)
    if len(positions) != len(stiffness) or len(positions) < 2:
        return (f'the stiffness table needs at least two points and one stiffness per position, got '
                f'{len(positions)} positions and {len(stiffness)} stiffnesses')
    if not all_finite(positions + stiffness):
        return 'the stiffness table holds a value that is not a finite number'
    if any(b <= a for a, b in zip(positions, positions[1:])):
        return 'the stiffness table\'s positions must be strictly increasing'
    if min(stiffness) <= 0.0:
        return f'every stiffness must be positive, got {min(stiffness):g} N/m'
    return ''


def design(config: DeflectionConfig = DeflectionConfig(), table: StiffnessTable | None = None) -> DeflectionResult:
    """The compensator for `config` (and, for force feedback, the stiffness `table`), or the
    reason why not."""
    try:
        reason = _refusal(config, table)
    except TypeError as exc:           # a value that is not a number at all
        reason = f'gain, cut-off, period and the table must be numbers ({type(exc).__name__})'
    if reason:
        return DeflectionResult(Status.FAILED, reason)
    return DeflectionResult(Status.OK, '', DeflectionDesign(config, table))


def force_feedback_error(desired: float, motor: float, force: float, stiffness: float) -> float:
    """FF error (§4.2, Fig. 4.1): z_d - (z_m + e_z), e_z = f / K(z_m) the deflection, in the
    direction of the force (Eq. 4.1); `motor` z_m, `force` f, `stiffness` K(z_m)."""
    return desired - (motor + force / stiffness)


def position_feedback_error(desired: float, arm: float) -> float:
    """PF error (§4.2, Fig. 4.2): z_d - z_a, z_a the measured arm-side position."""
    return desired - arm


class DeflectionCompensator:
    """One ORCA period per :meth:`step`: error in, (velocity reference, position correction)
    out; the robot gets z_d + correction and the velocity reference (module doc)."""

    def __init__(self, design_: DeflectionDesign):
        self.design = design_
        self._low_pass = design_.low_pass()
        self.correction = 0.0

    def step(self, error: float) -> tuple[float, float]:
        velocity = self._low_pass.step(error)
        self.correction += self.design.config.period * velocity
        return velocity, self.correction
