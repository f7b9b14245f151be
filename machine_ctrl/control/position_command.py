"""The command of a drive that closes its own position loop (drive type position_servo: an
industrial robot's joint, whose controller is given, Sörnmo section 2.4): its position
reference, led by the reference velocity,

    u = x_r + T_v v_r

For the joint loop x'' = w^2 (u - x) - 2 zeta w x' (hw_sim PositionServoAxis), T_v = 2 zeta / w
removes its lag on a ramp: the robot controller's own velocity feed-forward, as §4.2's "both
velocity and position references are continuously sent to the internal robot joint
controllers". T_v = 0 sends the reference alone. No state: the measurement is not used (the
robot's controller has its own).
"""
from __future__ import annotations

from machine_ctrl.control.law import Parameter, gains_change_problem, retune_checked
from machine_ctrl.model.config import AxisConfig, PositionCommandGains


class PositionCommand:
    parameters = (
        Parameter('velocity_lead', 's', 'T_v, the lead on the reference velocity, u = x_r + T_v v_r',
                  live='a feed-forward term without state: the command moves by Delta T_v v_r'),
    )

    @classmethod
    def from_axis(cls, gains: PositionCommandGains, axis: AxisConfig, period: float) -> PositionCommand:
        if axis.drive.type != 'position_servo':
            raise ValueError(f'axis {axis.name}: position_command sends a position reference; a {axis.drive.type} '
                             f'drive takes another command (position_command needs a position_servo drive)')
        return cls(gains)

    def __init__(self, gains: PositionCommandGains):
        self.gains = gains

    def retune_problem(self, gains: PositionCommandGains) -> str | None:
        return gains_change_problem(self, gains)

    def retune(self, gains: PositionCommandGains) -> None:
        retune_checked(self, gains)
        self.gains = gains

    def reset(self) -> None:
        """No state."""

    def step(self, x_r: float, v_r: float, a_r: float, x: float, v: float, acc: float = 0.0) -> float:
        return x_r + self.gains.velocity_lead * v_r
