"""Dual-stage feed drive coupling (Yuen thesis section 4.4, Fig. 4.9, Eqs. 4.77-4.80): the
tracking error of each coarse axis is added to the reference of its fine axis, so the sum
x = x_c + x_f follows the coarse reference with the fine stage's bandwidth.

    r_f' = r_f + sign * (r_c - x_c)        (sign -1 for z, seed-notes.md)

A Cartesian coupling (machine config ``cartesian_dual_stage``; Sörnmo Fig. 2.9, a robot and a
micro manipulator) does the same through the kinematics: the tool tip's deviation caused by
the coarse axes' errors, J_P,coarse (r_c - x_c), is cancelled by the fine axes,

    r_f' = r_f + pinv(J_P,fine) J_P,coarse (r_c - x_c)

with J_P the tool-tip position rows of the Jacobian at the reference (for a pair of parallel
axes this is the pair's law, the sign coming out of the kinematics). With a tracker (config
``cartesian_dual_stage.tracker``; Sörnmo §2.4-2.5: the robot's deviation is measured, the arm
deflects where no joint encoder sees it) the deviation is the tracker's instead:

    r_f' = r_f + pinv(J_P,fine) (P(r_c, q_f,home) - y)

with y the tracker's reading of the coarse stage's tool tip (the fine axes at home) and P the
forward kinematics' tool tip.

Mid-ranging (config ``cartesian_dual_stage.midranging``; Sörnmo Ch. 3): the fine stage's
stroke is small (§2.2: ~0.5 mm), and a lasting deviation (the arm's static deflection under the
milling force) would keep it off its middle for the whole cut. The valve-position-control
structure of Fig. 3.2 moves such a deviation over to the coarse stage: C_s' acts on the fine
stage's offset (the "valve position", its set point r_s = 0: the middle), and the coarse
stage's tool tip is moved by

    Delta_k = Delta_{k-1} + (h / T) J_P,fine dq_f,k        dq_c,k = pinv([J_P,coarse; J_O,coarse]) [Delta_k; 0]

(h the control period, dq_f,k the fine offsets of step k). With the coarse stage following its
reference fast compared with T, the coarse stage takes over 1/(T s + 1) of a deviation and the
fine stage keeps T s/(T s + 1) (after a step its offset decays with T): C_s' is a plain
integrator, the PI of §3.2 "designed using the same desired closed-loop system" T_s = 1/(T s + 1) with
the coarse loop taken as 1 (its proportional part is zero). The coarse move keeps the tool's
axis (J_O: the rows of the tool axis's direction, which a spin about the axis through the tip
does not change, so the 6 x n matrix has rank 5 at most: that spin gets the minimum-norm
solution, and singular values below PINV_RCOND of the largest count as zero). The deviation
is still taken against the unshifted reference: as the coarse stage moves by Delta, the
deviation it leaves (measured by the tracker, or by the encoders) shrinks by Delta, and so
does the fine stage's offset; the tool tip stays on the path.
This is VPC, not the adaptive IMC of Ch. 3 (machine_ctrl/control/midranging.py): the seed runs
its mid-ranging on two first-order loops in simulation and on two robots (§3.4, Fig. 3.8), not
on the machining robot with the micro manipulator.

Stroke: the fine axis must stay inside its stroke. The total fine reference is clipped to
the stroke shrunk by a margin (default 10 % of its width, assumed: room for the fine axis's
own tracking error) and slewed at no more than the fine axis's velocity limit, so a large
coarse error (a start far from the reference, a coarse fault) does not kick the table into
its end stop. A clipped or slewed step is reported as saturated and the coupling keeps
going — the fine stage then compensates only part of the error, it never faults. In normal
operation (um-level coarse errors) neither limit is active.

Same shape as a control law (machine_ctrl/control/law.py), over all axes at once:
``step(ref_pos, pos, tracker=None)`` -> offsets (in the order of MachineConfig.offset_axes:
the fine axes, then with mid-ranging the coarse axes), ``reset()``, declared ``parameters``.
Switched off, every offset is zero at once (the mid-ranging's take-over too, which starts
from zero when switched on again); a reset starts the take-over from zero as well.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from machine_ctrl.control.law import Parameter
from machine_ctrl.model.config import MachineConfig


class CouplingResult(NamedTuple):     # a NamedTuple: one is made per step (cheaper than a frozen dataclass)
    offsets: tuple[float, ...]       # added to each axis's reference, MachineConfig.offset_axes order
    saturated: tuple[bool, ...]      # per fine axis


class DualStageCoupling:
    parameters = (
        Parameter('margin', '1', 'fraction of the fine stroke kept free at each end'),
        Parameter('dual_stage', 'bool', 'coupling on (off: zero offsets); the dual_stage node parameter'),
    )

    def __init__(self, machine: MachineConfig, dual_stage: bool = True, margin: float = 0.10):
        index = {name: i for i, name in enumerate(machine.axis_names)}
        self.pairs = [(index[p.coarse], p.sign) for p in machine.dual_stage]
        self.fine_axes = machine.fine_axes
        self.offset_axes = machine.offset_axes
        self.fine = [index[name] for name in self.fine_axes]
        self.limits = []                 # per fine axis: lowest and highest total reference, slew per step
        for name in self.fine_axes:
            lo, hi = machine.axis(name).stroke
            shrink = margin * (hi - lo)
            self.limits.append((lo + shrink, hi - shrink, machine.axis(name).limits.velocity * machine.control_period))
        cartesian = machine.cartesian_dual_stage
        self.cartesian = None if cartesian is None else _CartesianDeviation(machine, index)
        self._off = CouplingResult((0.0,) * len(self.offset_axes), (False,) * len(self.fine))
        self.enabled = dual_stage
        self.reset()

    @property
    def enabled(self) -> bool:
        return self._enabled

    @enabled.setter
    def enabled(self, on: bool) -> None:
        """Switched off, the coupling forgets its motion at once: every offset is zero from the
        next step, and when switched on again it starts afresh."""
        self._enabled = bool(on)
        if not on:
            self.reset_motion()

    def reset(self) -> None:
        """Forget the last fine references (no slew limit on the next step), the mid-ranging's
        take-over and the saturation count; `enabled` stays as it is."""
        self.saturation_count = 0
        self.reset_motion()

    def reset_motion(self) -> None:
        """Forget the last fine references and the mid-ranging's take-over (both start from zero)."""
        self._last_total: list[float | None] = [None] * len(self.fine)
        if self.cartesian is not None:
            self.cartesian.reset()

    @property
    def uses_tracker(self) -> bool:
        """Whether :meth:`step` needs the tracker's reading (a Cartesian coupling with a tracker)."""
        return self.cartesian is not None and self.cartesian.uses_tracker

    def step(self, ref_pos, pos, tracker=None) -> CouplingResult:
        """ref_pos, pos: reference and measured position of every axis (machine order);
        `tracker`: the tracker's reading (x, y, z), required when :attr:`uses_tracker`."""
        if not self._enabled:
            return self._off
        corrections = [sign * (ref_pos[coarse] - pos[coarse]) for coarse, sign in self.pairs]
        if self.cartesian is not None:
            corrections += self.cartesian.corrections(ref_pos, pos, tracker)
        offsets, saturated = [], []
        for i, (fine, correction, (lo, hi, slew)) in enumerate(zip(self.fine, corrections, self.limits)):
            wanted = ref_pos[fine] + correction
            total = min(hi, max(lo, wanted))
            last = self._last_total[i]
            if last is not None:
                total = min(last + slew, max(last - slew, total))
            self._last_total[i] = total
            offsets.append(total - ref_pos[fine])
            saturated.append(total != wanted)
        self.saturation_count += sum(saturated)
        if self.cartesian is not None and self.cartesian.midranging:
            offsets += self.cartesian.midrange(offsets[len(self.pairs):])
        return CouplingResult(tuple(offsets), tuple(saturated))


class _CartesianDeviation:
    """The fine axes' corrections of a Cartesian coupling (module doc): dq_f solving
    J_P,fine dq_f = J_P,coarse (r_c - x_c) in the least-squares sense, J_P the tool-tip position
    rows of the Jacobian at the reference. J is evaluated again only when a reference axis has
    moved by more than JACOBIAN_STEP (in its own unit, m or rad: one max-norm over both) since
    the last evaluation (the coarse errors are small, so the change of J in between changes the
    corrections by a negligible fraction). ValueError when the fine axes cannot move the tool
    tip in as many independent directions as they are (at the machine's home)."""

    JACOBIAN_STEP = 1e-4         # m or rad, assumed: J's relative change over it is ~1e-4 at a 1 m reach
    # assumed: far above rounding (the spin's singular value is ~1e-17 of the largest) and far
    # below any direction the coarse axes really move the tool in
    PINV_RCOND = 1e-9

    def __init__(self, machine: MachineConfig, index: dict[str, int]):
        from machine_ctrl.model.kinematics import Kinematics
        self.kinematics = Kinematics.from_config(machine)
        self.coarse = np.array([index[n] for n in machine.cartesian_dual_stage.coarse])
        self.fine = np.array([index[n] for n in machine.cartesian_dual_stage.fine])
        self.uses_tracker = machine.tracker is not None
        midranging = machine.cartesian_dual_stage.midranging
        self._rate = None if midranging is None else machine.control_period / midranging.time_constant   # h / T
        self.fine_home = np.array(machine.home, float)[self.fine]
        at_home = self.kinematics.jacobian(np.array(machine.home))[:3, self.fine]
        if np.linalg.matrix_rank(at_home) < len(self.fine):
            raise ValueError(f'{machine.name}: cartesian_dual_stage: the fine axes '
                             f'{", ".join(machine.cartesian_dual_stage.fine)} do not move the tool tip in '
                             f'{len(self.fine)} independent directions (at home)')
        self.reset()

    @property
    def midranging(self) -> bool:
        return self._rate is not None

    def reset(self) -> None:
        """Forget the Jacobian and the mid-ranging's take-over (a reset coupling is a fresh one)."""
        self._at, self._map, self._fine_pinv, self._fine_jacobian, self._coarse_pinv = None, None, None, None, None
        self._taken_over = np.zeros(3)            # Delta, m: the tool-tip move given to the coarse stage

    def corrections(self, ref_pos, pos, tracker=None) -> list[float]:
        ref = np.asarray(ref_pos, float)
        if self._at is None or np.abs(ref - self._at).max() > self.JACOBIAN_STEP:
            full = self.kinematics.jacobian(ref)
            jacobian = full[:3]
            self._fine_jacobian = jacobian[:, self.fine]
            self._fine_pinv = np.linalg.pinv(self._fine_jacobian)
            self._map = self._fine_pinv @ jacobian[:, self.coarse]
            if self.midranging:
                self._coarse_pinv = np.linalg.pinv(full[:, self.coarse], rcond=self.PINV_RCOND)[:, :3]   # [Delta; 0]
            self._at = ref.copy()
        if not self.uses_tracker:
            error = ref[self.coarse] - np.asarray(pos, float)[self.coarse]
            return (self._map @ error).tolist()
        if tracker is None or len(tracker) != 3:
            raise ValueError(f'the coupling measures the deviation with a tracker: needs its reading (x, y, z), '
                             f'got {tracker!r}')
        coarse_ref = ref.copy()
        coarse_ref[self.fine] = self.fine_home
        deviation = self.kinematics.forward(coarse_ref)[0] - np.asarray(tracker, float)
        return (self._fine_pinv @ deviation).tolist()

    def midrange(self, fine_offsets) -> list[float]:
        """The coarse axes' offsets of this step (module doc): Delta += (h / T) J_P,fine dq_f, in
        joint space pinv([J_P; J_O]_coarse) [Delta; 0], at the Jacobian of the last
        :meth:`corrections` (which is called first in each step)."""
        self._taken_over = self._taken_over + self._rate * (self._fine_jacobian @ np.asarray(fine_offsets, float))
        return (self._coarse_pinv @ self._taken_over).tolist()


def apply_offsets(ref_pos, slots, offsets) -> list[float]:
    """The reference the servos see: the axes at `slots` get their offsets added."""
    ref = list(ref_pos)
    for i, offset in zip(slots, offsets):
        ref[i] += offset
    return ref
