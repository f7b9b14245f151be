"""Sampled axis references: position, velocity and acceleration of every axis at every
control step, the unit the servo consumes (streamed to nodes in chunks, stepped offline)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Reference:
    axis_names: tuple[str, ...]
    period: float
    position: np.ndarray        # (steps, axes), m or rad
    velocity: np.ndarray
    acceleration: np.ndarray

    def __post_init__(self):
        shape = (len(self.position), len(self.axis_names))
        for name in ('position', 'velocity', 'acceleration'):
            array = np.ascontiguousarray(getattr(self, name), dtype=float)
            if array.shape != shape:
                raise ValueError(f'reference {name} has shape {array.shape}, expected {shape}')
            if not np.isfinite(array).all():
                raise ValueError(f'reference {name} is not finite')
            setattr(self, name, array)

    def __len__(self) -> int:
        return len(self.position)

    def row(self, k: int) -> tuple[list[float], list[float], list[float]]:
        """Step k; past the end the last position is held at rest (never a jump)."""
        if k < len(self.position):
            return self.position[k].tolist(), self.velocity[k].tolist(), self.acceleration[k].tolist()
        return self.position[-1].tolist(), [0.0] * len(self.axis_names), [0.0] * len(self.axis_names)

    @classmethod
    def hold(cls, axis_names, period: float, position, steps: int) -> Reference:
        pos = np.tile(np.asarray(position, float), (steps, 1))
        return cls(tuple(axis_names), period, pos, np.zeros_like(pos), np.zeros_like(pos))
