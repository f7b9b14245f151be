"""The control laws by name: what ``axes.<axis>.control.law`` in a machine YAML selects.

Each entry names the class implementing :class:`~machine_ctrl.control.law.ControlLaw`, the
gains dataclass of its YAML section (``ControlConfig.<name>`` in machine_ctrl/model/config.py,
whose law fields are the one list of law names; test/test_control_interface.py checks that
both agree) and whether the servo adds the LuGre friction feed-forward
(``control.lugre_feedforward``) to its command. A new law is one module, one entry here and
its gains in the config schema; no other code branches on a law's name.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass

from machine_ctrl.control.law import ControlLaw
from machine_ctrl.model.config import (AxisConfig, H2Gains, LeadLagGains, LqgGains, PIDGains, PositionCommandGains,
                                       PPIGains, SlidingModeGains)


@dataclass(frozen=True)
class LawEntry:
    module: str                         # the module of the class implementing ControlLaw,
    name: str                           # imported at first use: a servo process imports the
    gains: type                         # laws its axes run only (h2's scipy.linalg is ~0.3 s)
    friction_feedforward: bool = False  # the servo adds the LuGre feed-forward, when configured

    @property
    def law(self) -> type:
        """The class implementing ControlLaw."""
        return getattr(importlib.import_module(self.module), self.name)


LAWS: dict[str, LawEntry] = {
    'sliding_mode': LawEntry('machine_ctrl.control.sliding_mode', 'SlidingModeController', SlidingModeGains,
                             friction_feedforward=True),
    'ppi': LawEntry('machine_ctrl.control.ppi', 'PPIController', PPIGains, friction_feedforward=True),
    'lead_lag': LawEntry('machine_ctrl.control.lead_lag', 'LeadLagController', LeadLagGains),
    'pid': LawEntry('machine_ctrl.control.pid', 'PIDController', PIDGains),
    'h2': LawEntry('machine_ctrl.control.h2', 'H2Controller', H2Gains),
    'position_command': LawEntry('machine_ctrl.control.position_command', 'PositionCommand', PositionCommandGains),
    'lqg': LawEntry('machine_ctrl.control.lqg', 'LqgLaw', LqgGains),
}


def law_entry(name: str) -> LawEntry:
    """The registered law `name`; ValueError naming the known laws otherwise."""
    entry = LAWS.get(name)
    if entry is None:
        raise ValueError(f'unknown control law {name!r} (known: {", ".join(sorted(LAWS))})')
    return entry


def make_law(axis: AxisConfig, period: float, law: str | None = None) -> ControlLaw:
    """The law of `axis` (its configured one, or `law` by name) with the gains of its
    machine config. ValueError, one line naming the axis, when it cannot be built."""
    control = axis.control
    if control is None:
        raise ValueError(f'axis {axis.name}: no control section in the machine config')
    name = law or control.law
    try:
        entry = law_entry(name)
    except ValueError as exc:
        raise ValueError(f'axis {axis.name}: {exc}') from None
    gains = getattr(control, name, None)
    if gains is None:
        raise ValueError(f'axis {axis.name}: law {name!r} has no gains in the machine config')
    return entry.law.from_axis(gains, axis, period)
