"""Per-axis servo: the configured control law of each axis (any law of
machine_ctrl/control/registry.py) plus, for the laws registered with it, the LuGre friction
feed-forward. No ROS; the servo node and the offline runner both call :meth:`ServoGroup.step`.

Feed-forward can be switched off (``feedforward=False``): the law then sees only the
reference position (v_r = a_r = 0) and no friction feed-forward — the servo loop alone, as
used to measure closed-loop bandwidths.

While running, :meth:`ServoGroup.set_feedforward` switches it at the first step whose
reference is at rest on every axis of the group (v_r = a_r = 0): under motion a switch would
step the command by (K_s + m_e lambda) v_r + m_e a_r for sliding mode (1.4-4.4 V of the
micromill's 5 V at 10 mm/s), at rest it changes nothing but the friction feed-forward, whose bristle state
starts from zero when switched on. :meth:`ServoGroup.retune` gives an axis's law new gains
from the next step (the law's own rules, machine_ctrl/control/law.py).
"""
from __future__ import annotations

from machine_ctrl.control.lugre import LuGreFeedforward
from machine_ctrl.control.registry import law_entry, make_law
from machine_ctrl.model.config import AxisConfig, MachineConfig


def make_friction_feedforward(axis: AxisConfig, period: float) -> LuGreFeedforward | None:
    gains = axis.control.lugre_feedforward
    return None if gains is None else LuGreFeedforward.from_axis(gains, axis, period)


class AxisServo:
    """One axis: law + optional friction feed-forward, itself a ControlLaw-shaped block."""

    def __init__(self, axis: AxisConfig, period: float, law: str | None = None, feedforward: bool = True):
        self.name = axis.name
        self.law = make_law(axis, period, law)
        self.law_name = law or axis.control.law
        uses_friction_ff = law_entry(self.law_name).friction_feedforward
        # built whether or not feed-forward is on at start, so that it can be switched on
        self.friction = make_friction_feedforward(axis, period) if uses_friction_ff else None
        self.feedforward = feedforward
        self._friction_active = self.friction if feedforward else None

    def set_feedforward(self, on: bool) -> None:
        """Feed-forward on/off from the next step (ServoGroup.set_feedforward waits for a rest);
        switched on, the friction feed-forward starts from zero bristle deflection."""
        on = bool(on)
        if on and not self.feedforward and self.friction is not None:
            self.friction.reset()
        self.feedforward = on
        self._friction_active = self.friction if on else None

    def reset(self) -> None:
        self.law.reset()
        if self.friction is not None:
            self.friction.reset()

    def step(self, x_r: float, v_r: float, a_r: float, x: float, v: float, acc: float = 0.0) -> float:
        if not self.feedforward:
            v_r = a_r = 0.0
        u = self.law.step(x_r, v_r, a_r, x, v, acc)
        if self._friction_active is not None:
            u += self._friction_active.step(v_r)
        return u


class ServoGroup:
    """The servos of any subset of a machine's axes (one node per axis, per stage, ...)."""

    def __init__(self, machine: MachineConfig, axis_names, laws: dict[str, str] | None = None,
                 feedforward: bool = True):
        laws = laws or {}
        unknown = set(axis_names) - set(machine.axis_names)
        if unknown:
            raise ValueError(f'{machine.name}: no axis {", ".join(sorted(unknown))}')
        self.axis_names = tuple(axis_names)
        self.servos = [AxisServo(machine.axis(n), machine.control_period, laws.get(n), feedforward)
                       for n in self.axis_names]
        self.feedforward = feedforward
        self.feedforward_requested: bool | None = None      # a switch waiting for a rest
        self._no_acceleration = (0.0,) * len(self.servos)

    def servo(self, axis: str) -> AxisServo:
        return self.servos[self.axis_names.index(axis)]

    def set_feedforward(self, on: bool) -> None:
        """Feed-forward on/off at the first step whose reference is at rest on every axis of
        the group (module docstring); `feedforward` says what is in effect."""
        on = bool(on)
        self.feedforward_requested = None if on == self.feedforward else on

    def retune(self, axis: str, gains) -> None:
        """New gains for the law of `axis` from the next step (ValueError with the law's
        reason, nothing changed, when refused)."""
        self.servo(axis).law.retune(gains)

    def reset(self) -> None:
        for servo in self.servos:
            servo.reset()

    @property
    def uses_acceleration(self) -> tuple[str, ...]:
        """The axes whose law uses the accelerometer's reading."""
        return tuple(s.name for s in self.servos if getattr(s.law, 'uses_acceleration', False))

    def step(self, ref_pos, ref_vel, ref_acc, pos, vel, acc=None) -> list[float]:
        """One command per axis of the group; all arguments in group order (`acc`: the
        accelerometer readings, None: 0.0 for every axis)."""
        if self.feedforward_requested is not None and not any(ref_vel) and not any(ref_acc):
            for servo in self.servos:
                servo.set_feedforward(self.feedforward_requested)
            self.feedforward, self.feedforward_requested = self.feedforward_requested, None
        acc = self._no_acceleration if acc is None else acc
        return [s.step(xr, vr, ar, x, v, am)
                for s, xr, vr, ar, x, v, am in zip(self.servos, ref_pos, ref_vel, ref_acc, pos, vel, acc)]
