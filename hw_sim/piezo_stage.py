"""One axis of Sörnmo's piezo micro manipulator (seed 004_33b29b0855b96c5a, Ch. 2) as the
outer position loop sees it: the input is the reference of the inner PID loop around the
piezo-actuator, scaled to the spindle's displacement (section 2.4: the inner loop linearizes
hysteresis and creep, so the outer model is linear, "the difference compared to the open loop
models ... is negligible"); the output is the spindle's displacement along the axis,
measured by a capacitive sensor (section 2.2).

    G(s) = prod_i w_i^2 / (s^2 + 2 zeta_i w_i s + w_i^2)  [x p / (s + p)]     (unit static gain)

The modes and the real pole are the axis's (:class:`PiezoAxisModel`); the identified
matrices are not printed (seed-notes.md), so the models are assumed from what the seed says
of them: orders 4 / 2 / 5 in x / y / z (section 2.3), the first eigenfrequency within
33-47 Hz in every axis and two visible in x and z (Fig. 2.5), y's at 47 Hz (section 2.6).

The command saturates at the stroke (+-half the ~0.5 mm range of section 2.2): the actuator
cannot extend further; the saturated samples are counted. Exact zero-order-hold
discretization; the sensor adds seeded Gaussian noise.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from machine_ctrl.model import modal
from machine_ctrl.model.config import AxisConfig


@dataclass(frozen=True)
class PiezoAxisModel:
    """One axis: lightly damped modes (Hz, zeta), an optional real pole (Hz), the stroke (m,
    half range: where the command saturates) and the capacitive sensor's noise (m RMS per
    sample)."""
    modes: tuple[tuple[float, float], ...]
    real_pole: float | None
    stroke: float
    sensor_noise: float

    def __post_init__(self):
        problems = [f'mode {f!r} Hz, zeta {z!r}: needs f > 0 and 0 < zeta < 1'
                    for f, z in self.modes if not (f > 0.0 and 0.0 < z < 1.0)]
        if not self.modes:
            problems.append('at least one mode is needed')
        if self.real_pole is not None and not self.real_pole > 0.0:
            problems.append(f'real pole {self.real_pole!r} Hz must be > 0')
        if not self.stroke > 0.0:
            problems.append(f'stroke {self.stroke!r} m must be > 0')
        if not self.sensor_noise >= 0.0:
            problems.append(f'sensor noise {self.sensor_noise!r} m must be >= 0')
        if problems:
            raise ValueError('; '.join(problems))

    @property
    def order(self) -> int:
        return 2 * len(self.modes) + (self.real_pole is not None)

    def state_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, C) of G(s) (machine_ctrl/model/modal.py)."""
        return modal.state_space([(2 * math.pi * f, z) for f, z in self.modes],
                                 None if self.real_pole is None else 2 * math.pi * self.real_pole)

    @classmethod
    def from_axis(cls, axis: AxisConfig) -> PiezoAxisModel:
        """The model of a machine's piezo axis: plant.modes (rad/s), the drive's command limit as
        the stroke, the sensor's noise."""
        plant = axis.plant
        return cls(tuple((m.omega / (2 * math.pi), m.zeta) for m in plant.modes),
                   plant.real_pole / (2 * math.pi) if plant.real_pole else None,
                   axis.drive.command_limit, plant.sensor_noise)


class PiezoAxis:
    """The axis stepped at `period` with a zero-order-held command (m), from rest at
    `position` (its steady state for that command)."""

    def __init__(self, model: PiezoAxisModel, period: float, rng: np.random.Generator | None,
                 position: float = 0.0):
        self.a, self.b, self.c = model.state_space()
        self.phi, self.gamma = modal.held(self.a, self.b, period)
        self.model, self.rng = model, rng
        self.state = -np.linalg.solve(self.a, self.b) * position
        self.command = position
        self.saturated = 0              # samples whose command exceeded the stroke

    @property
    def position(self) -> float:
        return float(self.c @ self.state)

    @property
    def velocity(self) -> float:
        return float(self.c @ (self.a @ self.state + self.b * self.command))

    def measure(self) -> float:
        """The capacitive sensor's reading of the position now."""
        noise = self.model.sensor_noise
        return self.position + (float(self.rng.normal(0.0, noise)) if noise > 0.0 else 0.0)

    def step(self, command: float) -> None:
        stroke = self.model.stroke
        if abs(command) > stroke:
            self.saturated += 1
            command = math.copysign(stroke, command)
        self.command = command
        self.state = self.phi @ self.state + self.gamma * command
