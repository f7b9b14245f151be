"""Cross-coupled contour control: the live contour-error estimates fed back to the axes, so
that the controller acts on the error that marks the part (the tool's distance from the path
and the tool axis's deviation from its orientation path), not on each axis's own error.

Koren & Lo's cross-coupling controller (CCC; Sencer Part I, seed 001, section 1 and refs.
[3], [4]) estimates the contour error from the axes' tracking errors, eps = -C_x e_x + C_y e_y
(seed 001 Eq. 1), passes it through a compensator W and gives each axis the share C_i W(eps) of
the correction. The variable-gain form (ref. [4]) lets C follow the path. Sencer Part I
builds the estimates this controller needs for five axes (Eqs. 17-34: the tool-tip contour
error eps in the Frenet frame, the orientation contour error eps_o), and their Part II feeds
them back. Part II is not among our seeds. What is built here is the cross-coupling
structure on Part I's two estimates, for any machine:

    c_P = k_p eps   + I_P,   I_P[k+1] = I_P[k] + k_i eps T         (tool tip, m)
    c_O = k_pO eps_o + I_O,  I_O[k+1] = I_O[k] + k_iO eps_o T      (tool axis, rad)
    dq_R = J_O,R^+ c_O                                             (rotary coupled axes)
    dq_L = J_P,L^+ (c_P - J_P,R dq_R)                              (linear coupled axes)

and dq is added to the references of the coupled axes. J_P and J_O are the tool-tip and
tool-axis rows of the Jacobian at the measured position (:meth:`Kinematics.forward_and_jacobian`);
their pseudo-inverses play Koren's coupling gains C, which for two orthogonal axes on a line
are exactly -sin(theta), cos(theta). The orientation correction goes first, then the linear
axes correct the tool tip, including the tip motion the rotary correction causes. A
correction through the reference works behind every per-axis law of
machine_ctrl/control/registry.py unchanged (their own feedback and feed-forward stay); the
axis loops track it within their bandwidth. Koren's CCC adds W(eps) to the axes' velocity
commands, so through a proportional position loop the two are the same.

**Only valid estimates** (machine_ctrl/contour/validity.py): an estimate whose bound on
|estimate - true contour error| is above the tolerance (a join, a corner, a reversal, the
last rows of a stop, a path end) is not used. Its channel then holds the last valid eps and
lets the weight w of the proportional term and the integral decay with the time constant
`fade` (machine config): the correction goes smoothly to zero while the estimates stay
invalid. With valid estimates back, w rises to 1 with the same time constant, so the
proportional term k_p w eps is not stepped in either (the correction moves by at most
k_p (1 - exp(-T/fade)) |eps| more than eps itself moves in a step).

**On and off at run time** (:meth:`ContourCoupling.set_enabled`): switched off, both channels
fade out the same way; switched on, they start from where the fade has left them (zero after
a few `fade`s) and fade in, with a fresh estimator (steps skipped while off break the step
order it relies on). While off and faded out the block costs nothing per step: no forward
kinematics, no estimate. The reference rows are kept as axis rows and converted to tool rows
(:func:`machine_ctrl.contour.estimation.tool_reference`) only while on, in blocks of BLOCK
steps aligned on the step count, up to the end of the block holding step + HORIZON. Which
rows an estimate sees is then a function of the step alone, so the servo node (reference
streamed in chunks, 3000 rows ahead) computes what the offline runner (the whole reference
at once) computes, bit for bit: with the control on from the start and the stream ahead of
each step's block. The servo node waits for that block (:meth:`ContourCoupling.has_rows_for`,
up to its input timeout from the first step that lacked it), so a stream lagging under
load delays a lock-step run, it does not change it; a stream later than the timeout, or a
chunk re-sent from an earlier step (which drops the rows after it until they come again),
leaves an estimate fewer rows: it may then be invalid and fade. The sources must stream at
least the block's reach ahead (horizon + BLOCK: 2500 rows at 10 kHz; their default
lookahead is 3000), or steps wait for the timeout.

**Gains** (machine YAML ``contour_control``): live between two steps (:meth:`retune`); the
integral is held as k_i * integral(eps), so a new k_i does not step the correction, and a new
k_p steps it by (Delta k_p) w eps, in proportion to the contour error.

Same shape as a control law (machine_ctrl/control/law.py) over several axes, like
machine_ctrl/control/dual_stage.py: declared ``parameters``, ``reset()``, ``retune_problem``,
``retune``; per step ``step(step, q) -> CouplingStep``, a status with a reason.
"""
from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass

import numpy as np

from machine_ctrl.contour.estimation import (OrientationEstimator, ToolTipEstimator, ToolTrajectory,
                                             tool_reference)
from machine_ctrl.contour.validity import machine_tolerances
from machine_ctrl.control.law import Parameter, retune_checked, value_problem
from machine_ctrl.model.config import ContourChannelGains, ContourControlConfig, MachineConfig
from machine_ctrl.model.kinematics import Kinematics


class CouplingStatus(enum.Enum):
    OFF = 'off'                 # switched off and faded out: no correction, nothing computed
    ACTIVE = 'active'           # every channel from a valid estimate of this step
    FADING = 'fading'           # a channel without a valid estimate, or switched off: its correction decays


@dataclass(frozen=True)
class CouplingStep:
    corrections: tuple[float, ...]     # added to the reference of each coupled axis (config order)
    status: CouplingStatus
    reason: str = ''                   # why FADING: the channels and their estimate's reason


class AxisRows:
    """The streamed reference of every axis by step (a chunk replaces everything from its first
    step on, as in ReferenceBuffer), on or off; converted to tool rows while on."""

    def __init__(self, n: int):
        self.first = 0
        self.rows = np.empty((3, 0, n))

    @property
    def end(self) -> int:
        return self.first + self.rows.shape[1]

    def add(self, first_step: int, q, qd, qdd) -> None:
        chunk = np.array([q, qd, qdd], float).reshape(3, -1, self.rows.shape[2])
        if not self.rows.shape[1] or not self.first <= first_step <= self.end:
            self.first, self.rows = first_step, chunk
        else:
            self.rows = np.concatenate((self.rows[:, :first_step - self.first], chunk), axis=1)

    def drop_before(self, step: int) -> None:
        cut = min(max(step - self.first, 0), self.rows.shape[1])
        if cut:
            self.rows, self.first = self.rows[:, cut:], self.first + cut


class _Channel:
    """One contour-error channel (module docstring): the last valid estimate, the weight w of
    the proportional term and the integral. With a valid estimate w rises towards 1, without
    one it and the integral decay, both by the factor exp(-T/fade) per step, so the
    proportional term k_p w eps neither steps in at a switch-on or a resume nor steps out."""

    def __init__(self):
        self.eps = np.zeros(3)
        self.weight = 0.0
        self.integral = np.zeros(3)          # k_i * integral(eps): a new k_i does not step it

    def update(self, gains: ContourChannelGains, eps, period: float, factor: float) -> None:
        self.eps = np.asarray(eps, float)
        self.weight = 1.0 - (1.0 - self.weight) * factor
        self.integral = self.integral + gains.integral * period * self.eps

    def decay(self, factor: float) -> None:
        self.weight *= factor
        self.integral = self.integral * factor

    def correction(self, gains: ContourChannelGains) -> np.ndarray:
        return gains.proportional * self.weight * self.eps + self.integral

    @property
    def quiet(self) -> bool:
        """Faded out: below 1 fm (frad), far under any sensor."""
        return max(self.weight * np.abs(self.eps).max(), np.abs(self.integral).max()) < 1e-15


CHANNELS = ('tool_tip', 'orientation')
# assumed: tool rows are made 500 steps at a time; the estimate of step k then sees the rows up
# to at most k + HORIZON + 500 steps, within the 3000 rows the reference sources stream ahead
BLOCK = 500


class ContourCoupling:
    parameters = (
        Parameter('axes', '', 'the coupled axes: the linear ones take the tool-tip correction, the rotary ones the '
                  'orientation correction'),
        Parameter('estimator', '', 'the tool-tip estimator, Sencer Eqs. (20), (22) or (26)'),
        Parameter('tool_tip.proportional', '1', 'k_p, the share of eps added to the tool tip\'s reference',
                  live='a step of (Delta k_p) w eps in the correction, ~ the contour error'),
        Parameter('tool_tip.integral', '1/s', 'k_i, integral gain on eps',
                  live='the integrator holds k_i * integral(eps): no step'),
        Parameter('orientation.proportional', '1', 'k_pO, the share of eps_o added to the tool axis\'s reference',
                  live='a step of (Delta k_pO) w eps_o in the correction, ~ the contour error'),
        Parameter('orientation.integral', '1/s', 'k_iO, integral gain on eps_o',
                  live='the integrator holds k_iO * integral(eps_o): no step'),
        Parameter('fade', 's', 'time constant of the correction\'s decay while its estimate is invalid or the '
                  'control is off', live='changes only how fast a decay goes on'),
    )

    def __init__(self, machine: MachineConfig, config: ContourControlConfig | None = None, enabled: bool = False,
                 kinematics: Kinematics | None = None):
        config = config or machine.contour_control
        if config is None:
            raise ValueError(f'{machine.name}: no contour_control section in the machine config')
        self.config = config
        self.period = machine.control_period
        self.kinematics = kinematics or Kinematics.from_config(machine)
        self.tolerances = machine_tolerances(machine)
        index = {name: i for i, name in enumerate(machine.axis_names)}
        self.axes = config.axes
        self._linear = [k for k, a in enumerate(config.axes) if machine.axis(a).kind == 'linear']
        self._rotary = [k for k, a in enumerate(config.axes) if machine.axis(a).kind == 'rotary']
        self._linear_columns = [index[config.axes[k]] for k in self._linear]
        self._rotary_columns = [index[config.axes[k]] for k in self._rotary]
        self.reference = AxisRows(len(machine.axes))
        self.trajectory = ToolTrajectory(self.period)
        self.history = self.trajectory.horizon + 2      # the rows an estimate may look back at, and 2
        self.enabled = bool(enabled)
        self._decay = math.exp(-self.period / config.fade)     # per step, while a channel fades
        self.reset()

    # -- the reference ---------------------------------------------------------------------

    def add_reference(self, first_step: int, q, qd, qdd) -> None:
        """Reference rows of every axis of the machine (machine order) from `first_step` on."""
        self.reference.add(first_step, q, qd, qdd)
        self._converted = min(self._converted, first_step)     # tool rows from here on are stale

    def _block_end(self, step: int) -> int:
        """The first step past the block holding step + horizon: the rows step's estimate reads."""
        return ((step + self.trajectory.horizon) // BLOCK + 1) * BLOCK

    def has_rows_for(self, step: int) -> bool:
        """Whether the reference rows that step's estimate reads are here (always while off):
        a node waits for them (its input timeout), so that what it computes does not depend
        on how far ahead the stream happens to be."""
        return not self.enabled or self.reference.end >= self._block_end(step)

    def _tool_rows(self, step: int) -> None:
        """Tool rows up to the end of the block holding step + horizon (module docstring), from
        the kept axis rows; switched on, from step - history."""
        rows = self.reference
        if not self._synced:
            self.trajectory = ToolTrajectory(self.period)
            self._converted = max(step - self.history, rows.first)
            self._synced = True
        end = min(rows.end, self._block_end(step))
        start = max(self._converted, rows.first)
        if start < end:
            q, qd, qdd = rows.rows[:, start - rows.first:end - rows.first]
            self.trajectory.add(start, *tool_reference(self.kinematics, q, qd, qdd))
            self._converted = end

    # -- switching and gains ----------------------------------------------------------------

    def set_enabled(self, on: bool) -> None:
        """On/off from the next step (module docstring: off fades out, on starts from there)."""
        on = bool(on)
        if on != self.enabled:
            self._estimators()
            self._synced = False        # tool rows are made while on only
        self.enabled = on
        self._idle = False

    def retune_problem(self, config: ContourControlConfig) -> str | None:
        """Why `config` cannot replace the one in use between two steps, or None: only the gains
        and `fade` may change (a channel can neither appear nor vanish), each value checked as
        the machine config checks it."""
        if type(config) is not ContourControlConfig:
            return f'must be ContourControlConfig, got {type(config).__name__}'
        for name in ('axes', 'estimator'):
            if getattr(config, name) != getattr(self.config, name):
                return f'{name}: fixed while running (a new value needs a new coupling)'
        if (config.orientation is None) != (self.config.orientation is None):
            return 'orientation: the channel cannot be added or removed while running'
        if (problem := value_problem(ContourControlConfig, 'fade', config.fade)) is not None:
            return f'fade: {problem}'
        for channel in CHANNELS:
            gains = getattr(config, channel)
            for f in dataclasses.fields(ContourChannelGains) if gains is not None else ():
                if (problem := value_problem(ContourChannelGains, f.name, getattr(gains, f.name))) is not None:
                    return f'{channel}.{f.name}: {problem}'
        return None

    def retune(self, config: ContourControlConfig) -> None:
        """From the next step (ValueError with the reason, nothing changed, when refused)."""
        retune_checked(self, config)
        self.config = config
        self._decay = math.exp(-self.period / config.fade)

    def reset(self) -> None:
        self.channels = {name: _Channel() for name in CHANNELS}
        self.invalid_steps = {name: 0 for name in CHANNELS}
        self.last = self._off = CouplingStep((0.0,) * len(self.axes), CouplingStatus.OFF)  # the last step's output
        self._idle = False              # off and faded out, seen at a step: nothing changes until switched on
        self._estimators()
        self._synced = False            # tool rows are made while on only
        self._converted = 0             # tool rows agree with the axis rows up to this step

    def _estimators(self) -> None:
        self.tip = ToolTipEstimator(self.config.estimator, self.tolerances[0])
        self.orientation = OrientationEstimator(self.tolerances[1])

    # -- one step ---------------------------------------------------------------------------

    @property
    def quiet(self) -> bool:
        return all(c.quiet for c in self.channels.values())

    def step(self, step: int, q) -> CouplingStep:
        """The corrections of control step `step` from the measured positions `q` of every axis
        (machine order); steps in order while on."""
        self.reference.drop_before(step - self.history)
        # off and faded out: the channels do not change until switched on (set_enabled, reset),
        # so `quiet` (numpy on the channels' vectors, ~5 us) is asked once, not every step
        if not self.enabled and (self._idle or self.quiet):
            self._idle = True
            self.trajectory.drop_before(step)
            self.last = self._off
            return self.last
        if self.enabled:
            self._tool_rows(step)
        self.trajectory.drop_before(step - self.history)
        p, o, jacobian = self.kinematics.forward_and_jacobian(q)
        if self.enabled:
            reasons = self._update(step, p, o)
        else:
            self._fade_all()
            reasons = ['switched off']
        tip = self.channels['tool_tip'].correction(self.config.tool_tip)
        corrections = np.zeros(len(self.axes))
        if self.config.orientation is not None:
            rotary = np.linalg.pinv(jacobian[3:, self._rotary_columns]) @ self.channels['orientation'].correction(
                self.config.orientation)
            corrections[self._rotary] = rotary
            tip = tip - jacobian[:3, self._rotary_columns] @ rotary
        corrections[self._linear] = np.linalg.pinv(jacobian[:3, self._linear_columns]) @ tip
        self.last = CouplingStep(tuple(corrections.tolist()),
                                 CouplingStatus.FADING if reasons else CouplingStatus.ACTIVE, '; '.join(reasons))
        return self.last

    def _fade_all(self) -> None:
        for channel in self.channels.values():
            channel.decay(self._decay)

    def _update(self, step: int, p, o) -> list[str]:
        """Step the estimators and the channels; the reasons of the channels left to fade."""
        if not self.trajectory.has(step):
            self._fade_all()
            return [f'no reference row for step {step}']
        row = self.trajectory.row(step)
        estimates = {'tool_tip': self.tip.estimate(self.trajectory, step, p.tolist(), row)}
        if self.config.orientation is not None:
            estimates['orientation'] = self.orientation.update(self.trajectory, step, o.tolist(), row)
        reasons = []
        for name, estimate in estimates.items():
            if estimate.valid:
                self.channels[name].update(getattr(self.config, name), estimate.vector, self.period, self._decay)
            else:
                self.channels[name].decay(self._decay)
                self.invalid_steps[name] += 1
                reasons.append(f'{name.replace("_", " ")} estimate invalid ({estimate.check.reason})')
        return reasons


def coupled_slots(coupling: ContourCoupling, axes) -> list[tuple[int, int]]:
    """(slot in `axes`, index in the coupling's corrections) of the coupled axes among `axes`."""
    return [(axes.index(a), k) for k, a in enumerate(coupling.axes) if a in axes]
