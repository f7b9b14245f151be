"""Path planning end to end (Yuen thesis Ch. 3): fit R(s) (Eq. 3.12) -> redundancy
resolution (Algorithm 1) -> feed optimization (§3.9) -> septic interpolation and time
sampling (§3.10, Eqs. 3.38-3.40), with the sampled references checked against the limits
and the strokes, and the tool pose of the sampled q checked against R(s).

Results, not exceptions (in the spirit of Ruckig's Result): :func:`plan` returns a
:class:`PlanResult` whose `status` (:class:`PlanStatus`) says whether it planned and, if
not, which kind of problem stopped it, with `reason`, a sentence naming it (never a bare
numpy message such as "Singular matrix") and the input that causes it: the point of the
path, the axis and by how much. Before the long stages, trajectory.reach checks the path's
geometry, workspace and strokes in a fraction of a second. The plan itself
(:class:`PlannedPath`) is `result.plan`; `result.unwrap()` returns it or raises
:class:`PlanError` (a ValueError) with the reason.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from enum import StrEnum

import numpy as np

from machine_ctrl.model.config import MachineConfig, load_machine
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.model.reference import Reference
from trajectory import reach, toolpath
from trajectory.axis_limits import TOLERANCE
from trajectory.feedrate import FeedLimits, FeedProfile, optimize_feed
from trajectory.moves import stroke_violation
from trajectory.redundancy import (RedundancySettings, Resolution, ResolutionFailed, initial_configuration,
                                   point_before, resolve, stroke_problems)
from trajectory.sampling import LimitsExceeded, SepticInterpolant, Sampling, resolve_rule, sample, sample_within
from trajectory.spline import ArcLengthPath

# assumed: process feed limit 10 mm/s. The thesis sets the process limit of its finishing
# pass at 10 [mm/s] (§6.2, Fig. 6.7: "the limitation of the feedrate will also come from the
# process itself, which was set at 10 [mm/s]"); no other process limit is stated.
DEFAULT_FEED = 10e-3
# assumed: <= 1000 feed nodes (optimize_feed takes ~2 s for 9 axes at this size; its grid
# error is a few %, which the sampler's verification absorbs).
MAX_FEED_NODES = 1000
# assumed: at most 6 sampling passes with local re-solves between them (each lowers the
# exceeded limits around the samples over them and re-solves the feed LP there,
# sampling.resolve_rule); helix, spiral and circle_xy at F = 0.01-1 m/s meet the limits
# within 5. What is left after them is removed by a global time stretch.
LOCAL_PASSES = 6


class PlanStatus(StrEnum):
    """What :func:`plan` came to (the value is the status's name in text and JSON)."""
    OK = 'ok'
    INVALID_INPUT = 'invalid_input'        # the feed, the machine, the tool path (too few points, too
                                           # close, too short, ...) or the settings
    UNREACHABLE = 'unreachable'            # a pose of the path cannot be reached by the axes (beyond
                                           # the workspace, or the start with the active axes)
    OUT_OF_STROKE = 'out_of_stroke'        # the path needs an axis beyond its stroke
    SINGULAR = 'singular'                  # the kinematics lose rank along the path (inside the strokes)
    EXCEEDS_LIMITS = 'exceeds_limits'      # no sampling within the velocity/acceleration/jerk limits
    FAILED = 'failed'                      # a numerical stage failed (e.g. the feed optimizer)


class PlanError(ValueError):
    """A plan field read from a PlanResult that is not ok (PlanResult.unwrap)."""

    def __init__(self, status: PlanStatus, reason: str):
        super().__init__(reason)
        self.status, self.reason = status, reason


@dataclass(frozen=True)
class PlannedPath:
    """A successful plan."""
    reference: Reference
    traversal_time: float            # s, first to last sample
    planning_time: float             # s, wall: reach check + fit + resolve + feed + sampling (not the pose check)
    max_position_deviation: float    # m, |FK(q(t_k)) - P(s_k)| over every sample
    max_orientation_deviation: float  # rad, angle between FK tool axis and O(s_k)
    peak_ratios: dict                # axis -> {'velocity', 'acceleration', 'jerk'}: peak / limit
    path: ArcLengthPath
    resolution: Resolution
    feed: FeedProfile
    sampling: Sampling

    def summary(self) -> dict:
        return {'traversal_time': self.traversal_time, 'planning_time': self.planning_time,
                'max_position_deviation': self.max_position_deviation,
                'max_orientation_deviation': self.max_orientation_deviation,
                'samples': len(self.reference), 'control_period': self.reference.period,
                'feed_scale': self.sampling.feed_scale, 'peak_ratios': self.peak_ratios,
                'peak_feed_ratio': self.sampling.feed_ratio}


@dataclass(frozen=True)
class PlanResult:
    """Outcome of :func:`plan`: `status`, `reason` ('' when ok), the wall time spent
    (`planning_time`, up to the failure if any) and, when ok, the plan (`plan`)."""
    status: PlanStatus
    reason: str = ''
    planning_time: float = 0.0
    plan: PlannedPath | None = None

    @property
    def ok(self) -> bool:
        return self.status == PlanStatus.OK

    def unwrap(self) -> PlannedPath:
        """The plan, or PlanError(status, reason) when there is none."""
        if self.plan is None:
            raise PlanError(self.status, self.reason or f'planning did not succeed ({self.status})')
        return self.plan


def load_toolpath(cl_or_name) -> toolpath.CLData:
    """CLData as given, a built-in name, or a CSV path."""
    if isinstance(cl_or_name, toolpath.CLData):
        return cl_or_name
    name = str(cl_or_name)
    if name in toolpath.BUILTIN:
        return toolpath.builtin(name)
    import os
    if not os.path.isfile(name):
        raise ValueError(f'{name}: not a built-in toolpath ({", ".join(toolpath.BUILTIN)}) '
                         'nor a CSV file')
    return toolpath.read_csv(name)


def feed_subgrid(n_intervals: int, max_nodes: int = MAX_FEED_NODES) -> int | None:
    """Stride of the largest uniform subgrid (including both ends) of a grid with n_intervals
    and at most max_nodes nodes, if it keeps >= max_nodes / 2 nodes; else None."""
    for count in range(min(n_intervals, max_nodes - 1), max(1, (max_nodes - 1) // 2) - 1, -1):
        if n_intervals % count == 0:
            return n_intervals // count
    return None


def feed_and_sample(interp: SepticInterpolant, fs, derivatives, limits: FeedLimits, period: float,
                    axis_names, tolerance: float = TOLERANCE, passes: int = LOCAL_PASSES):
    """Optimized feed profile on the nodes fs (path derivatives q', q'', q''' there) and its
    time sampling within `tolerance` x every limit by finite differences at `period`.
    Where the sampled references exceed a limit (the grid is coarser than some feature of
    q(s), e.g. the nullspace start-up transient, or the grid-level jerk is optimistic between
    nodes), that limit is lowered at the nodes there and the LP re-solved around them
    (sampling.resolve_rule, feedrate.refine_feed), and resampled, at most `passes` times;
    then a global time stretch (sampling.sample) is the fallback. Returns (the optimizer's
    first FeedProfile, Sampling); Sampling.passes counts every sampling pass (local ones,
    then the fallback's) and Sampling.feed_scale is the fallback's global factor (1 without
    it)."""
    profile = optimize_feed(fs, *derivatives, limits)
    local = sample_within(interp, profile.s, profile.b, limits, period, axis_names,
                          resolve_rule(profile.s, derivatives, limits), tolerance, passes)
    if local.within:
        return profile, local.sampling
    fallback = sample(interp, profile.s, local.feed_b, limits, period, axis_names, tolerance)
    return profile, replace(fallback, passes=passes + fallback.passes)


def pose_deviations(kinematics: Kinematics, q, p_path, o_path) -> tuple[float, float]:
    """Largest |FK position(q[k]) - p_path[k]| (m) and angle between the FK tool axis and
    o_path[k] (rad) over the rows k of q."""
    p, o = kinematics.forward_many(q)          # batched: ~1e-15 of Pinocchio's, far below what this checks
    cross = np.linalg.norm(np.cross(o, o_path), axis=1)
    angle = np.arctan2(cross, np.sum(o * o_path, axis=1))
    return float(np.max(np.linalg.norm(p - p_path, axis=1))), float(np.max(angle))


def plan(cl_or_name, machine, feed: float = DEFAULT_FEED, settings: RedundancySettings | None = None,
         q0=None, kinematics: Kinematics | None = None, max_feed_nodes: int = MAX_FEED_NODES) -> PlanResult:
    """Plan the toolpath (CLData, built-in name or CSV path) on `machine` (MachineConfig or
    name) with the process feed limit `feed` (m/s). Never raises for a path, feed or machine
    it cannot plan: the PlanResult says why (module docstring)."""
    start = time.perf_counter()

    def failed(status: PlanStatus, reason: str) -> PlanResult:
        return PlanResult(status, ' '.join(str(reason).split()), time.perf_counter() - start)

    if not (isinstance(feed, (int, float)) and math.isfinite(feed) and feed > 0):
        return failed(PlanStatus.INVALID_INPUT, f'feed must be a positive finite speed in m/s, got {feed!r}')
    try:
        if not isinstance(machine, MachineConfig):
            machine = load_machine(machine)
        kinematics = kinematics or Kinematics.from_config(machine)
        cl = load_toolpath(cl_or_name)
    except (ValueError, OSError) as exc:
        return failed(PlanStatus.INVALID_INPUT, str(exc))
    start = time.perf_counter()
    try:
        refusal = reach.check(cl, kinematics, machine, settings, q0)
    except ValueError as exc:          # settings, q0
        return failed(PlanStatus.INVALID_INPUT, str(exc))
    if refusal:
        return failed(PlanStatus(refusal.status), refusal.reason)
    try:
        path = ArcLengthPath.fit(cl)
    except ValueError as exc:
        return failed(PlanStatus.INVALID_INPUT, f'tool path: {exc}')
    try:
        if q0 is None:
            q0 = initial_configuration(path, kinematics, machine, settings)
            problems = stroke_problems(machine, q0)
            if problems:    # reach.check found the start pose inside the strokes: elsewhere
                return failed(PlanStatus.OUT_OF_STROKE, 'point 0 is reachable inside the strokes, but not in the '
                                                        'start configuration the planner takes (from home, each axis '
                                                        'moved in proportion to its stroke): ' + '; '.join(problems))
        res = resolve(path, kinematics, machine, settings, q0)
    except ResolutionFailed as exc:
        exact = None
        if exc.kind == 'out_of_stroke':   # a pose out of reach between the checked samples?
            exact = reach.out_of_reach_near(cl, kinematics, machine, point_before(path.knot_s, exc.s), settings, q0)
        return failed(PlanStatus(exact.status), exact.reason) if exact else failed(PlanStatus(exc.kind), exc.reason)
    except np.linalg.LinAlgError:
        return failed(PlanStatus.SINGULAR, 'the kinematics are singular at the start of the path')
    except ValueError as exc:          # settings, q0
        return failed(PlanStatus.INVALID_INPUT, str(exc))
    try:
        interp = SepticInterpolant.from_resolution(res)
        limits = FeedLimits.from_machine(machine, feed)
        n = len(res.s) - 1
        stride = feed_subgrid(n, max_feed_nodes)
        if stride is not None:
            idx = np.arange(0, n + 1, stride)
            fs, d1, d2, d3 = res.s[idx], res.dq[idx], res.ddq[idx], res.dddq[idx]
        else:   # no uniform subgrid of the right size: derivatives of the septic interpolant
            fs = np.linspace(res.s[0], res.s[-1], max_feed_nodes)
            d1, d2, d3 = (interp.evaluate(fs, k) for k in (1, 2, 3))
        profile, sampling = feed_and_sample(interp, fs, (d1, d2, d3), limits, machine.control_period,
                                            machine.axis_names)
    except LimitsExceeded as exc:
        return failed(PlanStatus.EXCEEDS_LIMITS, str(exc))
    except np.linalg.LinAlgError:
        return failed(PlanStatus.FAILED, 'the feed optimization or sampling met a singular system')
    except ValueError as exc:
        return failed(PlanStatus.FAILED, str(exc))
    planning_time = time.perf_counter() - start

    ref = sampling.reference
    problem = stroke_violation(machine, ref)
    if problem:
        return PlanResult(PlanStatus.OUT_OF_STROKE, f'the sampled references leave a stroke: {problem}', planning_time)
    ep, eo = pose_deviations(kinematics, ref.position, *path.evaluate(sampling.s))
    ratios = {name: {'velocity': float(r[0]), 'acceleration': float(r[1]), 'jerk': float(r[2])}
              for name, r in zip(machine.axis_names, sampling.peak_ratios)}
    planned = PlannedPath(ref, sampling.duration, planning_time, ep, eo, ratios, path, res, profile,
                          sampling)
    return PlanResult(PlanStatus.OK, '', planning_time, planned)
