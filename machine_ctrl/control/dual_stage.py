"""Dual-stage feed drive coupling (Yuen thesis section 4.4, Fig. 4.9, Eqs. 4.77-4.80): the
tracking error of each coarse axis is added to the reference of its fine axis, so the sum
x = x_c + x_f follows the coarse reference with the fine stage's bandwidth.

    r_f' = r_f + sign * (r_c - x_c)        (sign -1 for z, seed-notes.md)

Stroke: the fine axis must stay inside its stroke. The total fine reference is clipped to
the stroke shrunk by a margin (default 10 % of its width, assumed: room for the fine axis's
own tracking error) and slewed at no more than the fine axis's velocity limit, so a large
coarse error (a start far from the reference, a coarse fault) does not kick the table into
its end stop. A clipped or slewed step is reported as saturated and the coupling keeps
going — the fine stage then compensates only part of the error, it never faults. In normal
operation (um-level coarse errors) neither limit is active.

Same shape as a control law (machine_ctrl/control/law.py), over all axes at once:
``step(ref_pos, pos)`` -> offsets, ``reset()``, declared ``parameters``.
"""
from __future__ import annotations

from dataclasses import dataclass

from machine_ctrl.control.law import Parameter
from machine_ctrl.model.config import MachineConfig


@dataclass(frozen=True)
class CouplingResult:
    offsets: tuple[float, ...]       # added to each fine axis's reference, pair order
    saturated: tuple[bool, ...]


class DualStageCoupling:
    parameters = (
        Parameter('margin', '1', 'fraction of the fine stroke kept free at each end'),
        Parameter('dual_stage', 'bool', 'coupling on (off: zero offsets); the dual_stage node parameter'),
    )

    def __init__(self, machine: MachineConfig, dual_stage: bool = True, margin: float = 0.10):
        index = {name: i for i, name in enumerate(machine.axis_names)}
        self.pairs = []
        for pair in machine.dual_stage:
            lo, hi = machine.axis(pair.fine).stroke
            shrink = margin * (hi - lo)
            slew = machine.axis(pair.fine).limits.velocity * machine.control_period
            self.pairs.append((index[pair.coarse], index[pair.fine], pair.sign, lo + shrink, hi - shrink, slew))
        self.fine_axes = tuple(p.fine for p in machine.dual_stage)
        self.enabled = dual_stage
        self.reset()

    def reset(self) -> None:
        """Forget the last fine references (no slew limit on the next step) and the
        saturation count; `enabled` stays as it is."""
        self.saturation_count = 0
        self._last_total: list[float | None] = [None] * len(self.pairs)

    def step(self, ref_pos, pos) -> CouplingResult:
        """ref_pos, pos: reference and measured position of every axis (machine order)."""
        if not self.enabled:
            self._last_total = [None] * len(self.pairs)
            return CouplingResult((0.0,) * len(self.pairs), (False,) * len(self.pairs))
        offsets, saturated = [], []
        for i, (coarse, fine, sign, lo, hi, slew) in enumerate(self.pairs):
            wanted = ref_pos[fine] + sign * (ref_pos[coarse] - pos[coarse])
            total = min(hi, max(lo, wanted))
            last = self._last_total[i]
            if last is not None:
                total = min(last + slew, max(last - slew, total))
            self._last_total[i] = total
            offsets.append(total - ref_pos[fine])
            saturated.append(total != wanted)
        self.saturation_count += sum(saturated)
        return CouplingResult(tuple(offsets), tuple(saturated))


def apply_offsets(ref_pos, slots, offsets) -> list[float]:
    """The reference the servos see: the fine axes at `slots` get their offsets added."""
    ref = list(ref_pos)
    for i, offset in zip(slots, offsets):
        ref[i] += offset
    return ref
