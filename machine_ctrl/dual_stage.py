"""Dual-stage feed drive coupling (Yuen thesis section 4.4, Fig. 4.9, Eqs. 4.77-4.80): the
tracking error of each coarse axis is added to the reference of its fine axis, so the sum
x = x_c + x_f follows the coarse reference with the fine stage's bandwidth.

    r_f' = r_f + sign * (r_c - x_c)        (sign -1 for z, seed-notes.md)

Stroke: the fine axis must stay inside its stroke. The total fine reference is clipped to
the stroke shrunk by a margin (default 5 % of its width, assumed: room for the fine axis's
own tracking error); a clipped step is reported as saturated and the coupling keeps going —
the fine stage then compensates only part of the error, it never faults.
"""
from __future__ import annotations

from dataclasses import dataclass

from machine_ctrl.config import MachineConfig


@dataclass(frozen=True)
class CouplingResult:
    offsets: tuple[float, ...]       # added to each fine axis's reference, pair order
    saturated: tuple[bool, ...]


class DualStageCoupling:
    def __init__(self, machine: MachineConfig, enabled: bool = True, margin: float = 0.05):
        index = {name: i for i, name in enumerate(machine.axis_names)}
        self.pairs = []
        for pair in machine.dual_stage:
            lo, hi = machine.axis(pair.fine).stroke
            shrink = margin * (hi - lo)
            self.pairs.append((index[pair.coarse], index[pair.fine], pair.sign, lo + shrink, hi - shrink))
        self.fine_axes = tuple(p.fine for p in machine.dual_stage)
        self.enabled = enabled
        self.saturation_count = 0

    def update(self, ref_pos, pos) -> CouplingResult:
        """ref_pos, pos: reference and measured position of every axis (machine order)."""
        if not self.enabled:
            return CouplingResult((0.0,) * len(self.pairs), (False,) * len(self.pairs))
        offsets, saturated = [], []
        for coarse, fine, sign, lo, hi in self.pairs:
            wanted = ref_pos[fine] + sign * (ref_pos[coarse] - pos[coarse])
            total = min(hi, max(lo, wanted))
            offsets.append(total - ref_pos[fine])
            saturated.append(total != wanted)
        self.saturation_count += sum(saturated)
        return CouplingResult(tuple(offsets), tuple(saturated))
