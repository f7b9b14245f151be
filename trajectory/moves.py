"""Point-to-point moves with Ruckig: jerk-limited, time-optimal, all axes synchronized to
finish together — the approach to the start of a path from wherever the machine is, joint
goals, return home, and a smooth stop (feed hold) from any state.

Every move starts from the machine's current state (position, velocity, acceleration of
each axis) and respects each axis's velocity, acceleration and jerk limits from the
machine config (optionally scaled down). Durations are whole control periods (Ruckig's
discrete duration), so the last sample is exactly the goal, at rest. A goal outside the
strokes, or a stop that cannot end inside them, is refused with the reason.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ruckig import (ControlInterface, DurationDiscretization, InputParameter, Result, Ruckig,
                    Trajectory)

from machine_ctrl.model.config import MachineConfig
from machine_ctrl.model.reference import Reference


@dataclass(frozen=True)
class AxisState:
    position: tuple[float, ...]
    velocity: tuple[float, ...]
    acceleration: tuple[float, ...]

    @classmethod
    def at_rest(cls, position) -> AxisState:
        position = tuple(float(v) for v in position)
        zeros = (0.0,) * len(position)
        return cls(position, zeros, zeros)


def validate_goal(machine: MachineConfig, goal) -> np.ndarray:
    """Goal positions (axis order) as an array; ValueError naming the first problem."""
    goal = np.asarray(goal, dtype=float)
    if goal.shape != (len(machine.axes),):
        raise ValueError(f'goal needs {len(machine.axes)} positions ({" ".join(machine.axis_names)}), '
                         f'got {goal.size}')
    if not np.isfinite(goal).all():
        raise ValueError('goal holds NaN or inf')
    for axis, value in zip(machine.axes, goal):
        if not axis.in_stroke(value):
            raise ValueError(f'goal {value:g} {axis.unit} for {axis.name} is outside its stroke {axis.stroke}')
    return goal


def _input(machine: MachineConfig, start: AxisState, scale: float) -> InputParameter:
    if not 0.0 < scale <= 1.0:
        raise ValueError(f'limit scale must be in (0, 1], got {scale}')
    n = len(machine.axes)
    for name in ('position', 'velocity', 'acceleration'):
        values = getattr(start, name)
        if len(values) != n or not np.isfinite(values).all():
            raise ValueError(f'start {name} needs {n} finite values')
    inp = InputParameter(n)
    inp.current_position = list(start.position)
    inp.current_velocity = list(start.velocity)
    inp.current_acceleration = list(start.acceleration)
    inp.max_velocity = [scale * a.limits.velocity for a in machine.axes]
    inp.max_acceleration = [scale * a.limits.acceleration for a in machine.axes]
    inp.max_jerk = [scale * a.limits.jerk for a in machine.axes]
    inp.duration_discretization = DurationDiscretization.Discrete
    return inp


def _plan(machine: MachineConfig, inp: InputParameter) -> Reference:
    otg = Ruckig(len(machine.axes), machine.control_period)
    trajectory = Trajectory(len(machine.axes))
    result = otg.calculate(inp, trajectory)
    if result not in (Result.Working, Result.Finished):
        raise ValueError(f'Ruckig cannot plan this move: {result}')
    steps = int(round(trajectory.duration / machine.control_period))
    samples = [trajectory.at_time(k * machine.control_period) for k in range(steps + 1)]
    position, velocity, acceleration = (np.array([s[i] for s in samples]) for i in range(3))
    _check_extrema(machine, trajectory)
    return Reference(machine.axis_names, machine.control_period, position, velocity, acceleration)


def _check_extrema(machine: MachineConfig, trajectory: Trajectory) -> None:
    for axis, extrema in zip(machine.axes, trajectory.position_extrema):
        if axis.stroke is not None and not (axis.stroke[0] <= extrema.min and extrema.max <= axis.stroke[1]):
            raise ValueError(f'{axis.name} would reach [{extrema.min:.6g}, {extrema.max:.6g}] {axis.unit}, '
                             f'outside its stroke {axis.stroke}')


def move_to(machine: MachineConfig, goal, start: AxisState | None = None, scale: float = 1.0,
            minimum_duration: float = 0.0) -> Reference:
    """Time-optimal jerk-limited move from `start` (default: at rest at home) to `goal`
    (at rest), sampled at the control period; it takes at least `minimum_duration` s."""
    goal = validate_goal(machine, goal)
    start = start or AxisState.at_rest(machine.home)
    inp = _input(machine, start, scale)
    inp.target_position = goal.tolist()
    inp.target_velocity = [0.0] * len(goal)
    inp.target_acceleration = [0.0] * len(goal)
    if minimum_duration > 0.0:
        inp.minimum_duration = minimum_duration
    return _plan(machine, inp)


def through_waypoints(machine: MachineConfig, start, names, points, times) -> Reference:
    """Joint goal (trajectory_msgs/JointTrajectory semantics): from `start` (axis positions,
    at rest) through every point of `points` (values for the axes `names`, a subset; the
    others keep their position), stopping at each. `times` (s from the start) are either
    all zero (each move time-optimal) or strictly increasing: arrive at point i no earlier
    than times[i]. ValueError naming the first problem."""
    index = _axis_columns(machine, names)
    if not points:
        raise ValueError('joint goal has no points')
    if len(times) != len(points):
        raise ValueError(f'{len(times)} times for {len(points)} points')
    times = [float(t) for t in times]
    if not np.isfinite(times).all():
        raise ValueError('time_from_start holds NaN or inf')
    timed = any(t != 0.0 for t in times)
    if timed and not all(b > a for a, b in zip([0.0] + times, times)):
        raise ValueError(f'time_from_start must be all zero or strictly increasing from > 0, got {times}')
    position = np.array(start, dtype=float)
    goals = []
    for i, values in enumerate(points):
        values = np.asarray(values, dtype=float)
        if values.shape != (len(index),):
            raise ValueError(f'point {i}: {values.size} positions for {len(index)} joints')
        position = position.copy()
        position[index] = values
        try:
            goals.append(validate_goal(machine, position))
        except ValueError as exc:
            raise ValueError(f'point {i}: {exc}') from None
    segments, state, previous = [], AxisState.at_rest(start), 0.0
    for goal, t in zip(goals, times):
        segment = move_to(machine, goal, state, minimum_duration=(t - previous) if timed else 0.0)
        segments.append(segment)
        state, previous = AxisState.at_rest(goal), t
    return concatenate(segments)


def _axis_columns(machine: MachineConfig, names) -> list[int]:
    names = list(names)
    if not names:
        raise ValueError('joint goal names no joints')
    if len(set(names)) != len(names):
        raise ValueError('duplicate joint names')
    unknown = [n for n in names if n not in machine.axis_names]
    if unknown:
        raise ValueError(f'unknown joints {", ".join(unknown)} (axes: {" ".join(machine.axis_names)})')
    return [machine.axis_names.index(n) for n in names]


def stroke_violation(machine: MachineConfig, reference: Reference) -> str:
    """'' if every sampled position is inside its axis's stroke, else the first offender."""
    for i, axis in enumerate(machine.axes):
        if axis.stroke is None:
            continue
        lo, hi = reference.position[:, i].min(), reference.position[:, i].max()
        if lo < axis.stroke[0] or hi > axis.stroke[1]:
            return f'{axis.name} reaches [{lo:.6g}, {hi:.6g}] {axis.unit}, outside its stroke {axis.stroke}'
    return ''


def concatenate(references) -> Reference:
    """References played back to back. Each later one starts with the row the previous one
    ended on (a move from where the previous stopped); that row is played once."""
    first = references[0]
    return Reference(first.axis_names, first.period,
                     *(np.concatenate([getattr(first, f)] + [getattr(r, f)[1:] for r in references[1:]])
                       for f in ('position', 'velocity', 'acceleration')))


def home(machine: MachineConfig, start: AxisState, scale: float = 1.0) -> Reference:
    return move_to(machine, machine.home, start, scale)


def smooth_stop(machine: MachineConfig, start: AxisState, scale: float = 1.0) -> Reference:
    """Feed hold: bring every axis to rest as fast as its limits allow (Ruckig's velocity
    interface), ending wherever that is; refused if that end lies outside a stroke."""
    inp = _input(machine, start, scale)
    inp.control_interface = ControlInterface.Velocity
    inp.target_velocity = [0.0] * len(machine.axes)
    inp.target_acceleration = [0.0] * len(machine.axes)
    return _plan(machine, inp)
