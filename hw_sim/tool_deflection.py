"""The deflection of a compliant machine's structure under the milling force (Sörnmo, seed
004_33b29b0855b96c5a, Ch. 4 and 5), as hw_sim steps it with the axes: the machine config's
``simulation.tool_compliance`` (machine_ctrl.model.config.ToolComplianceConfig). SI units.

The tool tip's true position relative to the workpiece is the rigid one, P(q) from the true
axis positions, plus a deflection d along the face normal (the workpiece frame's z): the
encoders, on the motor side of the structure, do not see d; the ground truth and a tracker
do. One structural mode, per control period k (h = control period):

* process force (Eq. 5.3, f = K_f (x_p - integral f / D_f), with x_p' = v w the penetration
  rate): f' = K_f v w - (K_f / D_f) f, solved exactly for v w held over the period; steady
  f = D_f v (Eq. 5.4). v is the rigid tool tip's speed along the face over the period, w the
  engagement: the depth engaged over the cut's depth, max(0, depth - z) / depth (deeper cuts
  push harder, in proportion, as the mechanistic force does), times, on the face, a linear
  ramp over the tool's diameter at each edge of the block (0 with the tool just outside, 1
  with it fully inside; assumed: the engaged arc is not linear in the position, a ramp is the
  simplest shape with the right ends). As in hw_sim/robot_compliance.py, the force is modulated
  by the tooth passing, 1 + ripple sin(2 pi f_t t), and by a factor per tooth 1 + variation g_j
  (g_j seeded unit Gaussian), and does not depend on the deflection (the removed depth is not
  fed back; the workpiece is a fresh face everywhere, material removed by an earlier pass is
  not remembered): assumptions of this model. The force acts on the tool along +z (out of the
  material), so the tool tip moves away from the face by f / k statically: Eq. (4.1), f = k x.
* structure (Ch. 4, Eq. 4.1; Fig. 4.5): m d'' + c d' + k(x) d = f with k(x) the configured
  stiffness along the face's x, m = k_0 / (2 pi f_e)^2 and c = 2 zeta sqrt(k_0 m), integrated
  by semi-implicit Euler at the control period (the config refuses w h > 0.05). The mode is
  driven by the force only: the excitation by the machine's own acceleration (the deflection
  experiment's motor-side coupling) is not modelled here (assumed; on a path at constant
  feed it is zero).

Every random draw comes from one ``random.Random`` seeded from the machine's simulation.seed,
so a run is reproducible bit for bit; :func:`deflections` replays the model over recorded
true positions (what an offline run hands the bag writer) with the same numbers as hw_sim.
"""
from __future__ import annotations

import math
import random
from typing import Callable

import numpy as np

from machine_ctrl.model.config import FaceMillingConfig, MachineConfig, ToolComplianceConfig

ToolTip = Callable[[tuple], np.ndarray]      # true axis positions -> 4x4 tool pose in the workpiece frame


def engagement(milling: FaceMillingConfig, x: float, y: float, z: float) -> float:
    """w at rigid tool-tip position (x, y, z) in the workpiece frame (module doc)."""
    axial = max(0.0, milling.depth - z) / milling.depth
    if axial == 0.0:
        return 0.0
    width = 2.0 * milling.tool_radius
    w = axial
    for s, (lo, hi) in ((x, milling.block_x), (y, milling.block_y)):
        w *= min(1.0, max(0.0, (s - lo + milling.tool_radius) / width)) * \
            min(1.0, max(0.0, (hi - s + milling.tool_radius) / width))
    return w


class ToolDeflection:
    """The module doc's force and mode, stepped once per control period by :meth:`step` with
    the rigid tool tip at the period's end. `force` (N, on the tool along the workpiece's z)
    and `deflection` (m, the tool tip's displacement along z) are the values at the current
    step."""

    def __init__(self, config: ToolComplianceConfig, period: float, seed: int, tip: tuple[float, float, float]):
        self.config, self.milling, self.h = config, config.milling, period
        w = 2.0 * math.pi * config.eigenfrequency
        self.mass = config.stiffness / (w * w)
        self.viscous = 2.0 * config.damping * math.sqrt(config.stiffness * self.mass)
        self.decay = math.exp(-period * self.milling.interaction_stiffness / self.milling.removal)
        self.wavenumber = 2.0 * math.pi / config.stiffness_wavelength
        self.rng = random.Random(f'{seed}:tool_compliance')
        self.step_index, self.tooth, self.chip = 0, -1, 1.0
        self.force, self.deflection, self.deflection_velocity = 0.0, 0.0, 0.0
        self.tip = tip

    def stiffness_at(self, x: float) -> float:
        c = self.config
        return c.stiffness + c.stiffness_variation * math.sin(self.wavenumber * x)

    def modulation(self) -> float:
        """The tooth-passing ripple and the tooth's own factor over the current period."""
        m = self.milling
        t = self.step_index * self.h
        tooth = math.floor(t * m.tooth_frequency)
        while self.tooth < tooth:                    # one draw per tooth, in order
            self.tooth += 1
            self.chip = 1.0 + m.variation * self.rng.gauss(0.0, 1.0)
        return (1.0 + m.ripple * math.sin(2.0 * math.pi * m.tooth_frequency * t)) * self.chip

    def step(self, tip: tuple[float, float, float]) -> None:
        """Period k -> k + 1: the mode under the force of period k, then the force from the
        tool's motion over the period (`tip`: the rigid tool tip at its end)."""
        h, m = self.h, self.mass
        x0 = self.tip[0]
        load = self.force * self.modulation()
        a = (load - self.viscous * self.deflection_velocity - self.stiffness_at(x0) * self.deflection) / m
        self.deflection_velocity += h * a
        self.deflection += h * self.deflection_velocity
        speed = math.hypot(tip[0] - x0, tip[1] - self.tip[1]) / h
        drive = self.milling.removal * speed * engagement(self.milling, *tip)
        self.force = self.decay * self.force + (1.0 - self.decay) * drive
        self.tip = tip
        self.step_index += 1


def rigid_tip(tool_pose: ToolTip, position) -> tuple[float, float, float]:
    p = tool_pose(position)[:3, 3]
    return float(p[0]), float(p[1]), float(p[2])


def deflected(pose: np.ndarray, deflection: float) -> np.ndarray:
    """The 4x4 tool pose `pose` (workpiece frame) with the tool tip moved by `deflection` along z."""
    out = np.array(pose, dtype=float)
    out[2, 3] += deflection
    return out


def deflections(machine: MachineConfig, tool_pose: ToolTip, true_positions) -> np.ndarray:
    """The deflection at each step of a run whose true axis positions are the rows of
    `true_positions` (step 0 first), as hw_sim computes it; zeros for a machine without
    tool_compliance."""
    rows = np.asarray(true_positions, dtype=float)
    out = np.zeros(len(rows))
    config = machine.simulation.tool_compliance
    if config is None or not len(rows):
        return out
    model = ToolDeflection(config, machine.control_period, machine.simulation.seed,
                           rigid_tip(tool_pose, tuple(rows[0].tolist())))
    for k in range(1, len(rows)):
        model.step(rigid_tip(tool_pose, tuple(rows[k].tolist())))
        out[k] = model.deflection
    return out
