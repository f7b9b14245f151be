"""Quick checks of a tool path (CL data: tool tips in m, unit tool axes, workpiece frame)
against a machine, run by planner.plan before the long planning so that a path the machine
cannot follow is refused within a fraction of a second with a reason naming the point:

1. geometry the machine resolves: consecutive tool tips at least the finest linear sensor
   resolution apart, and the whole path at least MIN_LENGTH long (invalid_input);
2. the workspace: every tool tip within the machine's reach, a sound bound on |P| from the
   kinematic chains (unreachable);
3. the strokes: the poses of up to SAMPLES points, spread evenly over the path, solved one
   after the other (PoseSolver.weighted, from the previous one), and any solution outside a
   stroke confirmed by the nearest configuration inside the strokes (PoseSolver.inside)
   missing the pose by more than REACH_TOLERANCE; the points between the last good sample
   and that one are then solved too, and the first out of reach is named with each axis
   outside its stroke and by how much (out_of_stroke).

A pose the Newton solve cannot reach at all is left to the planner's own stages (its
initial configuration says why). Points between the samples are checked by the redundancy
resolution, and :func:`out_of_reach_near` names the point and the excess when the
resolution breaks down there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from machine_ctrl.model.config import MachineConfig
from machine_ctrl.model.kinematics import Kinematics
from trajectory.axis_limits import outside_stroke, stroke_excess
from trajectory.redundancy import PoseSolver, RedundancySettings
from trajectory.toolpath import CLData, closer_than, spacing_text

# assumed: a path must be at least 1 µm long. Below ~0.5 µm (measured on both machines,
# lines and arcs of 6 and 24 points) the feed optimization's 1000-node grid is so fine that
# its second differences (1/Δs² > 4e18 1/m²) leave the LP solver's coefficient range
# (HiGHS: "Model error"); 1 µm keeps a factor 2 from there.
MIN_LENGTH = 1e-6
# assumed: 64 sampled poses: ~0.15 ms each (a few Newton steps from the previous one), so
# the check costs ~10 ms; violations between samples are found by the resolution.
SAMPLES = 64
# assumed: 1 µm / 1 µrad. A pose the nearest configuration inside the strokes misses by
# more is out of reach; the bounded solve ends within 1e-12 of reachable poses (measured
# 1e-18 to 1e-13), and a pose out of reach by less is left to the resolution.
REACH_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Refusal:
    """Why a path is refused: `status` (a planner.PlanStatus value) and `reason`."""
    status: str
    reason: str


def reach_radius(kinematics: Kinematics, machine: MachineConfig) -> float:
    """A bound (m) on the distance of the tool tip from the workpiece origin over every axis
    position inside the strokes. Each chain is followed from the base: up to its first
    rotary joint its fixed offsets add up exactly (prismatic joints translate without
    turning what follows) and its prismatic joints add at most their travel; from there on,
    rotations keep lengths, so each offset and travel adds at most its length. With p_t, p_w
    the ends of the tool and workpiece chains, |P| = |R_w^T (p_t - p_w)| <= |c_t - c_w| +
    the rest of both chains (c: the exact parts)."""
    model = kinematics.model
    axes = {a.name: a for a in machine.axes}

    def chain(frame_name: str) -> tuple[np.ndarray, float]:
        frame = model.frames[model.getFrameId(frame_name)]
        joints, joint = [], frame.parentJoint
        while joint > 0:
            joints.append(joint)
            joint = model.parents[joint]
        placement, rotated, slack = pin.SE3.Identity(), False, 0.0
        for joint in reversed(joints):
            axis = axes[model.names[joint]]
            if rotated:
                slack += float(np.linalg.norm(model.jointPlacements[joint].translation))
            else:
                placement = placement * model.jointPlacements[joint]
            if axis.kind == 'linear':
                slack += max(abs(axis.stroke[0]), abs(axis.stroke[1]))
            else:
                rotated = True
        if rotated:
            return placement.translation, slack + float(np.linalg.norm(frame.placement.translation))
        return (placement * frame.placement).translation, slack

    (c_w, slack_w), (c_t, slack_t) = chain(machine.workpiece_frame), chain(machine.tool_frame)
    return float(np.linalg.norm(c_t - c_w)) + slack_w + slack_t


def check(cl: CLData, kinematics: Kinematics, machine: MachineConfig, settings: RedundancySettings | None = None,
          start=None, samples: int = SAMPLES) -> Refusal | None:
    """The first problem along the path found by the three checks of the module docstring
    (geometry first), or None. `start`: the configuration the solves start from (default:
    the machine's home)."""
    problem = _geometry(cl, machine)
    if problem:
        return problem
    beyond = _beyond_workspace(cl, kinematics, machine)
    end = len(cl) if beyond is None else beyond.point
    indices = sorted({i for i in _spread(len(cl), samples) if i < end} | ({end - 1} if end else set()))
    return (_strokes(cl, PoseSolver(kinematics, machine, settings), indices,
                     machine.home if start is None else start)
            or (beyond.refusal if beyond else None))


def out_of_reach_near(cl: CLData, kinematics: Kinematics, machine: MachineConfig, point: int,
                      settings: RedundancySettings | None = None, start=None,
                      samples: int = SAMPLES) -> Refusal | None:
    """The stroke check of :func:`check` on the sampled points up to `point` and on every
    point within one sample spacing of it: the exact reason when the resolution broke down
    near `point` because a pose there is out of reach inside the strokes, else None."""
    spacing = math.ceil(len(cl) / samples)
    near = range(max(point - spacing, 0), min(point + spacing + 1, len(cl)))
    indices = sorted({i for i in _spread(len(cl), samples) if i < near.start} | set(near))
    return _strokes(cl, PoseSolver(kinematics, machine, settings), indices,
                    machine.home if start is None else start)


def _spread(n: int, samples: int) -> list[int]:
    """Up to `samples` point indices spread evenly over n points, first and last included."""
    return sorted(set(np.linspace(0, n - 1, min(n, samples)).round().astype(int).tolist()))


def _geometry(cl: CLData, machine: MachineConfig) -> Refusal | None:
    resolution = min(a.sensor_resolution for a in machine.axes if a.kind == 'linear')
    close = closer_than(cl.positions, resolution)
    if close is not None:
        return Refusal('invalid_input', f'{spacing_text(cl.positions, close, resolution)}, the finest sensor '
                                        f'resolution of the linear axes of {machine.name}')
    length = float(np.sum(np.linalg.norm(np.diff(cl.positions, axis=0), axis=1)))
    if length < MIN_LENGTH:
        return Refusal('invalid_input', f'the path is {length:.3g} m long (need >= {MIN_LENGTH:g} m for the '
                                        'feed optimization)')
    return None


@dataclass(frozen=True)
class _Beyond:
    point: int
    refusal: Refusal


def _beyond_workspace(cl: CLData, kinematics: Kinematics, machine: MachineConfig) -> _Beyond | None:
    """The first point whose tool tip is farther from the workpiece origin than
    reach_radius, or None."""
    radius = reach_radius(kinematics, machine)
    distance = np.linalg.norm(cl.positions, axis=1)
    beyond = np.flatnonzero(distance > radius)
    if not len(beyond):
        return None
    i = int(beyond[0])
    tip = ', '.join(f'{v:.6g}' for v in cl.positions[i])
    return _Beyond(i, Refusal('unreachable', f'point {i}: tool tip ({tip}) m is beyond the workspace: '
                                             f'{distance[i]:.3g} m from the workpiece origin, where no tool tip '
                                             f'of {machine.name} is farther than {radius:.3g} m'))


def _strokes(cl: CLData, solver: PoseSolver, indices, start) -> Refusal | None:
    """Solve the poses of the points `indices` (increasing) one after the other from
    `start`; at the first confirmed out of reach inside the strokes, solve the points
    between the last good one and it too and name the first out of reach."""
    q, last = np.array(start, dtype=float), None
    for i in indices:
        found, q_next = _solve(cl, solver, i, q)
        if found is None:
            return None
        if found:
            if last is not None and i > last + 1:     # refine: the first one out in between
                return _strokes(cl, solver, range(last + 1, i + 1), q)
            return _out_of_stroke(solver.machine, i, found)
        q, last = q_next, i
    return None


def _solve(cl: CLData, solver: PoseSolver, i: int, q) -> tuple[list[str] | None, np.ndarray]:
    """(problems, q) for point i from configuration q: problems [] when the pose is reachable
    inside the strokes (q: a configuration there); when it is not (confirmed by
    PoseSolver.inside), the axes of the weighted solution outside their strokes, with the
    excess; None when the Newton solve does not converge."""
    p, o = cl.positions[i], cl.axes[i]
    q_i, ep, eo = solver.weighted(p, o, q)
    if not (ep <= 1e-12 and eo <= 1e-12):           # not converged (or NaN from a bad start)
        return None, q
    axes = solver.machine.axes
    share = np.array([stroke_excess(a, v) / (0.5 * (a.stroke[1] - a.stroke[0])) if a.stroke else 0.0
                      for a, v in zip(axes, q_i)])
    if not share.any():
        return [], q_i
    q_in, ep, eo = solver.inside(p, o, q_i)
    if ep <= REACH_TOLERANCE and eo <= REACH_TOLERANCE:
        return [], q_in
    # the axes that carry the excess: >= 1 % of the largest excess (each in its half-stroke)
    return [outside_stroke(a, v) for a, v, x in zip(axes, q_i, share) if x >= 0.01 * share.max()], q_i


def _out_of_stroke(machine: MachineConfig, i: int, problems: list[str]) -> Refusal:
    where = ('the path starts out of reach inside the strokes' if i == 0
             else f'the path leaves the reach of the strokes at point {i}')
    return Refusal('out_of_stroke', f'{where}: {"; ".join(problems)}' + (' (point 0)' if i == 0 else ''))
