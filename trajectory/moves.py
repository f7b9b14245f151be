"""Point-to-point moves with Ruckig: jerk-limited, time-optimal, all axes synchronized to
finish together — the approach to the start of a path from wherever the machine is, joint
goals, return home, and a smooth stop (feed hold) from any state.

Every move starts from the machine's current state (position, velocity, acceleration of
each axis) and respects each axis's velocity, acceleration and jerk limits from the
machine config (optionally scaled down). Durations are whole control periods (Ruckig's
discrete duration), so the last sample is the goal, at rest, to Ruckig's precision (~1e-12
m or rad from a start away from home; a caller that joins a move to a given row closes that
gap, as freeform._land_on does). On an unlimited axis a move is planned relative to its
start (_Motion), so Ruckig never computes with a spindle's accumulated turns. Refused with a reason
naming the axis (ValueError): a goal outside its stroke (by how much) or, on an unlimited
axis, beyond its range (axis_limits.unlimited_range), a stop that cannot end inside the
strokes; for joint goals also the point: a time_from_start the axes cannot meet (with the
earliest they can), a goal longer than MAX_GOAL_STEPS.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
from ruckig import (ControlInterface, DurationDiscretization, InputParameter, Result, Ruckig, RuckigError,
                    Trajectory)

from machine_ctrl.model.config import MachineConfig
from machine_ctrl.model.reference import Reference
from trajectory.axis_limits import amount, outside_range, outside_stroke

# assumed: a joint goal lasts at most 2^20 control steps (105 s on the micromill at 10 kHz,
# 17.5 min on trt_5axis at 1 kHz). Its references are sampled whole before the motion starts
# (3 x 8 bytes per axis and step: 226 MB for 9 axes) in the trajectory node's thread
# (~6 µs per step: ~6 s); a longer goal would hold the node and its memory (a 1e9 rad goal
# on c_f would take 1.6e8 s).
MAX_GOAL_STEPS = 2**20


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
    """Goal positions (axis order, m / rad) as an array; ValueError naming the first problem
    and its axis: wrong count, NaN or inf, outside the stroke (by how much), beyond the
    range of an unlimited axis (axis_limits.unlimited_range)."""
    goal = np.asarray(goal, dtype=float)
    if goal.shape != (len(machine.axes),):
        raise ValueError(f'goal needs {len(machine.axes)} positions ({" ".join(machine.axis_names)}), '
                         f'got {goal.size}')
    for axis, value in zip(machine.axes, goal):
        if not math.isfinite(value):
            raise ValueError(f'{axis.name} at {value}: NaN or inf is not a position')
        problem = outside_stroke(axis, value) or outside_range(axis, value, machine.control_period)
        if problem:
            raise ValueError(problem)
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


@dataclass(frozen=True)
class _Motion:
    """A Ruckig trajectory planned relative to `offset`: each unlimited axis's start position
    (0 for the others), so Ruckig computes with the distance to go, never with a spindle's
    thousands of radians; sampling adds the offset back, one rounding per sample."""
    trajectory: Trajectory
    offset: np.ndarray
    unlimited: np.ndarray           # indices of the axes without a stroke


def _calculate(machine: MachineConfig, inp: InputParameter) -> _Motion:
    """Ruckig's trajectory for `inp` (positions made relative to the start on unlimited
    axes); ValueError when Ruckig cannot plan it."""
    unlimited = np.array([i for i, a in enumerate(machine.axes) if a.stroke is None], int)
    offset = np.zeros(len(machine.axes))
    offset[unlimited] = np.asarray(inp.current_position)[unlimited]
    if unlimited.size:
        inp.current_position = (np.asarray(inp.current_position) - offset).tolist()
        if inp.control_interface == ControlInterface.Position:
            inp.target_position = (np.asarray(inp.target_position) - offset).tolist()
    otg = Ruckig(len(machine.axes), machine.control_period)
    trajectory = Trajectory(len(machine.axes))
    try:
        result = otg.calculate(inp, trajectory)
    except RuckigError as exc:      # Ruckig raises on inputs it fails to solve numerically
        dof = re.search(r'step (\d),? (?:in )?dof: (\d+)', str(exc))
        where = (f' (Ruckig found no profile for {machine.axis_names[int(dof[2])]} in its step {dof[1]})'
                 if dof and int(dof[2]) < len(machine.axes) else '')
        raise ValueError(f'Ruckig cannot plan this move{where}') from None
    if result not in (Result.Working, Result.Finished):
        raise ValueError(f'Ruckig cannot plan this move: {result}')
    return _Motion(trajectory, offset, unlimited)


def _steps(machine: MachineConfig, motion: _Motion) -> int:
    return int(round(motion.trajectory.duration / machine.control_period))


def _sample(machine: MachineConfig, motion: _Motion) -> Reference:
    """The trajectory sampled at the control period; ValueError if it leaves a stroke."""
    trajectory = motion.trajectory
    _check_extrema(machine, trajectory)
    samples = [trajectory.at_time(k * machine.control_period) for k in range(_steps(machine, motion) + 1)]
    position, velocity, acceleration = (np.array([s[i] for s in samples]) for i in range(3))
    if motion.unlimited.size:
        position[:, motion.unlimited] += motion.offset[motion.unlimited]
    return Reference(machine.axis_names, machine.control_period, position, velocity, acceleration)


def _plan(machine: MachineConfig, inp: InputParameter) -> Reference:
    return _sample(machine, _calculate(machine, inp))


def _check_extrema(machine: MachineConfig, trajectory: Trajectory) -> None:
    """The strokes of the limited axes (their positions are planned as they are)."""
    for axis, extrema in zip(machine.axes, trajectory.position_extrema):
        problem = outside_stroke(axis, extrema.min, 'would reach') or outside_stroke(axis, extrema.max, 'would reach')
        if problem:
            raise ValueError(problem)


def _move_input(machine: MachineConfig, goal, start: AxisState | None, scale: float,
                minimum_duration: float) -> InputParameter:
    goal = validate_goal(machine, goal)
    start = start or AxisState.at_rest(machine.home)
    inp = _input(machine, start, scale)
    inp.target_position = goal.tolist()
    inp.target_velocity = [0.0] * len(goal)
    inp.target_acceleration = [0.0] * len(goal)
    if minimum_duration > 0.0:
        inp.minimum_duration = minimum_duration
    return inp


def move_to(machine: MachineConfig, goal, start: AxisState | None = None, scale: float = 1.0,
            minimum_duration: float = 0.0) -> Reference:
    """Time-optimal jerk-limited move from `start` (default: at rest at home) to `goal`
    (at rest), sampled at the control period; it takes at least `minimum_duration` s."""
    return _plan(machine, _move_input(machine, goal, start, scale, minimum_duration))


def through_waypoints(machine: MachineConfig, start, names, points, times) -> Reference:
    """Joint goal (trajectory_msgs/JointTrajectory semantics): from `start` (axis positions,
    at rest) through every point of `points` (values for the axes `names`, a subset; the
    others keep their position), stopping at each. `times` (s from the start) are either
    all zero (each move time-optimal) or strictly increasing: the move to point i takes
    times[i] - times[i - 1], rounded up to whole control periods. ValueError naming
    the point and the first problem: a bad name, value or time, an axis position its axis
    does not accept (validate_goal), a time the axes cannot meet within their limits (with
    the earliest they can), a goal longer than MAX_GOAL_STEPS control steps."""
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
    longest = MAX_GOAL_STEPS * machine.control_period
    if times[-1] > longest:
        raise ValueError(f'point {len(times) - 1}: time_from_start {times[-1]:g} s is beyond the '
                         f'{longest:g} s a joint goal may last ({MAX_GOAL_STEPS} control steps)')
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
    motions, state, previous, steps = [], AxisState.at_rest(start), 0.0, 0
    for i, (goal, t) in enumerate(zip(goals, times)):
        # at full speed all the way: a goal far beyond a goal's length is refused before Ruckig,
        # which finds no profile for one of 1e9 rad (its numbers, not the goal, would be named)
        least = max(abs(g - x) / axis.limits.velocity for g, x, axis in zip(goal, state.position, machine.axes))
        if steps * machine.control_period + least > longest:
            raise ValueError(f'point {i}: the joint goal would last at least '
                             f'{steps * machine.control_period + least:.6g} s up to it, beyond the {longest:g} s a '
                             f'joint goal may last ({MAX_GOAL_STEPS} control steps)')
        motion = _calculate(machine, _move_input(machine, goal, state, 1.0, (t - previous) if timed else 0.0))
        if timed and max(motion.trajectory.independent_min_durations) > t - previous:
            raise ValueError(f'point {i}: ' + _too_early(machine, state.position, goal, t, previous,
                                                         motion.trajectory))
        steps += _steps(machine, motion)
        if steps > MAX_GOAL_STEPS:
            raise ValueError(f'point {i}: the joint goal would last {steps * machine.control_period:.6g} s '
                             f'up to it, beyond the {longest:g} s a joint goal may last '
                             f'({MAX_GOAL_STEPS} control steps)')
        motions.append(motion)
        state, previous = AxisState.at_rest(goal), t
    return concatenate([_sample(machine, motion) for motion in motions])


def _too_early(machine: MachineConfig, start, goal, t: float, previous: float, trajectory: Trajectory) -> str:
    """Why a move from `start` (at time `previous`) cannot reach `goal` at time `t`: the axis
    whose own time-optimal move takes longest (Ruckig's independent minimum durations, which
    exceed t - previous), its distance, the speed the time asks for (against its limit) and
    the earliest time it can be there, the next control step after its time-optimal move."""
    fastest = trajectory.independent_min_durations
    k = int(np.argmax(fastest))
    axis = machine.axes[k]
    distance = abs(goal[k] - start[k])
    window = t - previous
    speed = distance / window
    limits = axis.limits
    if speed > limits.velocity:
        needs = f'needs {amount(speed, axis.unit + "/s")} (limit {amount(limits.velocity, axis.unit + "/s")})'
    else:
        needs = (f'needs more than its acceleration and jerk limits allow ({limits.acceleration:g} '
                 f'{axis.unit}/s², {limits.jerk:g} {axis.unit}/s³)')
    earliest = previous + math.ceil(fastest[k] / machine.control_period) * machine.control_period
    return (f'{amount(distance, axis.unit)} in {amount(window, "s")} on {axis.name} {needs}; earliest '
            f'time_from_start {earliest:.6g} s (on the control-period grid)')


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
    """'' if every sampled position is inside its axis's stroke, else the first offender:
    'x_c reaches 0.0512 m at t = 1.2 s, outside its stroke [-0.05, 0.05] m by 1.2 mm'."""
    for i, axis in enumerate(machine.axes):
        if axis.stroke is None:
            continue
        column = reference.position[:, i]
        k = int(np.argmax(np.maximum(axis.stroke[0] - column, column - axis.stroke[1])))
        problem = outside_stroke(axis, column[k], 'reaches', f' at t = {k * reference.period:.6g} s')
        if problem:
            return problem
    return ''


def move_to_state(machine: MachineConfig, target: AxisState, start: AxisState, scale: float = 1.0) -> Reference:
    """Time-optimal jerk-limited move from `start` to `target` (position, velocity and
    acceleration: e.g. the first row of a cut that begins under way), sampled at the control
    period; its last row is `target` (Ruckig's discrete duration). ValueError with the reason."""
    goal = validate_goal(machine, target.position)
    inp = _input(machine, start, scale)
    for name in ('velocity', 'acceleration'):
        values = getattr(target, name)
        if len(values) != len(goal) or not np.isfinite(values).all():
            raise ValueError(f'target {name} needs {len(goal)} finite values')
    inp.target_position = goal.tolist()
    inp.target_velocity = [float(v) for v in target.velocity]
    inp.target_acceleration = [float(a) for a in target.acceleration]
    return _plan(machine, inp)


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
