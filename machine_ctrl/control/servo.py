"""Per-axis servo: the configured control law of each axis (sliding mode, P-PI or
lead-lag + notch) plus, for the linear motors, the LuGre friction feed-forward. No ROS;
the servo node and the offline runner both call :meth:`ServoGroup.update`.

Feed-forward can be switched off (``feedforward=False``): the law then sees only the
reference position (v_r = a_r = 0) and no friction feed-forward — the servo loop alone, as
used to measure closed-loop bandwidths.
"""
from __future__ import annotations

from machine_ctrl.model.config import AxisConfig, MachineConfig
from machine_ctrl.control.lead_lag import LeadLagController
from machine_ctrl.control.lugre import LuGreFeedforward, StribeckCurve
from machine_ctrl.control.ppi import PPIController
from machine_ctrl.control.sliding_mode import SlidingModeController


def make_law(axis: AxisConfig, period: float, law: str | None = None):
    control = axis.control
    if control is None:
        raise ValueError(f'axis {axis.name}: no control section in the machine config')
    law = law or control.law
    gains = getattr(control, law, None)
    if gains is None:
        raise ValueError(f'axis {axis.name}: law {law!r} has no gains in the machine config')
    if law == 'sliding_mode':
        drive = axis.drive
        return SlidingModeController(gains, drive.mass / drive.gain, drive.damping / drive.gain, period)
    if law == 'ppi':
        return PPIController(gains, period)
    return LeadLagController(gains, period)


def make_friction_feedforward(axis: AxisConfig, period: float) -> LuGreFeedforward | None:
    ff = axis.control.lugre_feedforward
    if ff is None:
        return None
    curve = StribeckCurve.symmetric(ff.coulomb, ff.static, ff.stribeck_velocity)
    return LuGreFeedforward(curve, ff.sigma0, ff.sigma1, axis.drive.gain, period)


class AxisServo:
    def __init__(self, axis: AxisConfig, period: float, law: str | None = None, feedforward: bool = True):
        self.name = axis.name
        self.law = make_law(axis, period, law)
        uses_friction_ff = (law or axis.control.law) in ('sliding_mode', 'ppi')
        self.friction = make_friction_feedforward(axis, period) if feedforward and uses_friction_ff else None
        self.feedforward = feedforward

    def update(self, x_r: float, v_r: float, a_r: float, x: float, v: float) -> float:
        if not self.feedforward:
            v_r = a_r = 0.0
        u = self.law.update(x_r, v_r, a_r, x, v)
        if self.friction is not None:
            u += self.friction.update(v_r)
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

    def update(self, ref_pos, ref_vel, ref_acc, pos, vel) -> list[float]:
        """One command per axis of the group; all arguments in group order."""
        return [s.update(xr, vr, ar, x, v)
                for s, xr, vr, ar, x, v in zip(self.servos, ref_pos, ref_vel, ref_acc, pos, vel)]
