"""The one interface of every control law, in the spirit of ros2_controllers (the law is
logic apart from plumbing: no topics, no parameters server, no clock) and python-control
(plain numbers in, plain numbers out).

A law controls one axis. Per control period the servo calls

    u = law.step(x_r, v_r, a_r, x, v)

with the reference (position, velocity, acceleration) and the measurement (position,
velocity) of its axis as plain floats, in SI units, and gets the command in the drive's
command unit. Plain floats on purpose: the step runs at 10 kHz for every axis in Python, and
packing reference and measurement into objects per call would cost more than most laws.

``reset()`` returns the law to the state it was built in (a reset law given the same inputs
reproduces its first run bit for bit). ``parameters`` declares the fields of the law's
gains section of the machine YAML (``axes.<axis>.control.<law>``, values and range checks
in machine_ctrl/model/config.py) with unit and meaning. ``from_axis(gains, axis, period)``
builds the law for one axis of a machine.

Adding a law: its gains dataclass and a field of that name in ``ControlConfig``
(machine_ctrl/model/config.py), a module here with a class implementing :class:`ControlLaw`,
and one entry in machine_ctrl/control/registry.py. Nothing else names laws.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, runtime_checkable

from machine_ctrl.model.config import AxisConfig


@dataclass(frozen=True)
class Parameter:
    """One declared parameter of a control block; for a law, a field of its gains section in
    the machine YAML."""
    name: str
    unit: str             # SI; '1' for dimensionless; the rotary unit in parentheses
    description: str      # the symbol and the equation it appears in


@runtime_checkable
class ControlLaw(Protocol):
    """One axis's control law (see the module docstring)."""

    parameters: ClassVar[tuple[Parameter, ...]]

    @classmethod
    def from_axis(cls, gains: Any, axis: AxisConfig, period: float) -> ControlLaw: ...

    def reset(self) -> None: ...

    def step(self, x_r: float, v_r: float, a_r: float, x: float, v: float) -> float: ...
