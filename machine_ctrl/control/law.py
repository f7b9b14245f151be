"""The one interface of every control law, in the spirit of ros2_controllers (the law is
logic apart from plumbing: no topics, no parameters server, no clock) and python-control
(plain numbers in, plain numbers out).

A law controls one axis. Per control period the servo calls

    u = law.step(x_r, v_r, a_r, x, v, acc)

with the reference (position, velocity, acceleration) and the measurement (position,
velocity, and the accelerometer's reading acc where the axis has one, else 0.0) of its axis
as plain floats, in SI units, and gets the command in the drive's command unit. A law that
uses acc says so with ``uses_acceleration = True`` (an attribute; absent means False), and
refuses to be built for an axis without an accelerometer. A law whose command depends on
the position error x_r - x alone (a unity-feedback loop, e.g. the lead-lag) says so with
``error_feedback = True`` (absent: False): its open-loop gain then follows from the closed
loop's, L = T / (1 - T) (machine_ctrl/experiments/tracking.frf). ``design_bandwidth``, where a
law has one, is the bandwidth its gains were designed for, rad/s (what a seed reports as the
loop's bandwidth). Plain floats on purpose: the step runs at 10 kHz for every axis in Python, and
packing reference and measurement into objects per call would cost more than most laws.

``reset()`` returns the law's state to where it was built (it keeps the gains in use; a
reset law given the same inputs and gains reproduces its first run bit for bit).
``parameters`` declares the fields of the law's gains section of the machine YAML
(``axes.<axis>.control.<law>``, values and range checks in machine_ctrl/model/config.py)
with unit and meaning, and which of them are *live*: safe to change between two steps of a
running machine, with the reason. ``from_axis(gains, axis, period)`` builds the law for one
axis of a machine; ``gains`` is the gains dataclass in use.

Retuning (a new parameter set while running): ``retune_problem(gains)`` says why the law
cannot take ``gains`` (a dataclass like ``gains``, e.g. ``dataclasses.replace(law.gains,
gain=60.0)``) between two steps, or None; ``retune(gains)`` takes them from the next step on
(ValueError with that reason, and nothing changes, when refused). Only live parameters may
change, each value is checked as the machine config checks it (finite; > 0 or >= 0 by the
field's metadata), and the law may add its own conditions (e.g. a stable discrete loop).
:func:`gains_change_problem` is the common part. The servo node offers the live parameters
as ROS parameters without knowing any law.

Adding a law: its gains dataclass and a field of that name in ``ControlConfig``
(machine_ctrl/model/config.py), a module here with a class implementing :class:`ControlLaw`
(its live gains declared with the reason they are safe; ``retune_problem`` at least
:func:`gains_change_problem`, ``retune`` after :func:`retune_checked`), and one entry in
machine_ctrl/control/registry.py. Nothing else names laws.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, runtime_checkable

from machine_ctrl.model.config import AxisConfig


@dataclass(frozen=True)
class Parameter:
    """One declared parameter of a control block; for a law, a field of its gains section in
    the machine YAML. `live`: why changing it between two steps is safe ('' : fixed when the
    block is built)."""
    name: str
    unit: str             # SI; '1' for dimensionless; the rotary unit in parentheses
    description: str      # the symbol and the equation it appears in
    live: str = ''


@runtime_checkable
class ControlLaw(Protocol):
    """One axis's control law (see the module docstring)."""

    parameters: ClassVar[tuple[Parameter, ...]]
    gains: Any

    @classmethod
    def from_axis(cls, gains: Any, axis: AxisConfig, period: float) -> ControlLaw: ...

    def reset(self) -> None: ...

    def step(self, x_r: float, v_r: float, a_r: float, x: float, v: float, acc: float = 0.0) -> float: ...

    def retune_problem(self, gains: Any) -> str | None: ...

    def retune(self, gains: Any) -> None: ...


def live_parameters(block) -> tuple[Parameter, ...]:
    """The parameters of a law (class or instance) that may change while it runs."""
    return tuple(p for p in block.parameters if p.live)


def value_check(gains_type, name: str) -> str:
    """How the machine config checks the gains field `name`: 'positive', 'nonnegative' or ''."""
    for f in dataclasses.fields(gains_type):
        if f.name == name:
            return f.metadata.get('check', '')
    raise KeyError(name)


def value_problem(gains_type, name: str, value) -> str | None:
    """Why the machine config would refuse `value` for the field `name`, or None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f'must be a number, got {value!r}'
    if not math.isfinite(value):
        return f'must be finite, got {value}'
    check = value_check(gains_type, name)
    if check == 'positive' and value <= 0:
        return f'must be > 0, got {value:g}'
    if check == 'nonnegative' and value < 0:
        return f'must be >= 0, got {value:g}'
    return None


def gains_change_problem(law, gains) -> str | None:
    """The common part of ``retune_problem``: `gains` is of the law's gains type, only live
    parameters differ from ``law.gains``, and each changed value passes the machine config's
    check. The reason names the field: ``gain: must be > 0, got -1``."""
    if type(gains) is not type(law.gains):
        return f'gains must be {type(law.gains).__name__}, got {type(gains).__name__}'
    live = {p.name for p in live_parameters(law)}
    for f in dataclasses.fields(gains):
        old, new = getattr(law.gains, f.name), getattr(gains, f.name)
        if new == old:
            continue
        if f.name not in live:
            return f'{f.name}: fixed while running (a new value needs a new law)'
        if (problem := value_problem(type(gains), f.name, new)) is not None:
            return f'{f.name}: {problem}'
    return None


def retune_checked(law, gains) -> None:
    """Raise ValueError with ``law.retune_problem(gains)`` if there is one."""
    problem = law.retune_problem(gains)
    if problem is not None:
        raise ValueError(problem)
