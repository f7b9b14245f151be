"""Planning ([3/7] trajectory.planner.plan) against TOPP-RA (toppra) on the built-in spiral and
helix on the 9-axis micromill. Issue [3/7] target: our (jerk-limited) traversal time, of the
final sampled reference, <= 1.3 x TOPP-RA's time with velocity and acceleration limits only
(TOPP-RA has no jerk limit: a lower bound).

Per path and process feed limit F:

* ours: plan(name, machine, feed=F) - fit, redundancy resolution (Δs = 20 µm), feed
  optimization on the planner's uniform subgrid (<= 1000 nodes), septic interpolation and
  time sampling at the control period with local re-solves until every reference is
  within 1.001 x its limits by finite differences. Reported: the final sampled traversal
  time (first to last sample), the optimizer's grid-level time (FeedProfile.duration() of
  the optimized profile, before the sampling's re-solves), local passes, the global
  fallback scale (1: none), the largest finite-difference ratio to a limit, and the planning
  time (PlanResult.planning_time: fit + resolve + feed + sampling).
* TOPP-RA 0.6, in the same run on the same resolved path: ta.SplineInterpolator(s, [q, s])
  through the planner's resolved q (cubic, not-a-knot), gridpoints = the planner's feed
  nodes, JointVelocityConstraint + JointAccelerationConstraint (default Interpolation
  discretization) with the same per-axis limits, ParametrizeConstAccel, rest to rest. The
  process feed limit F on sdot (s is arc length) is a "virtual joint" equal to s, appended
  to q, with velocity limit F and an inactive acceleration limit. Time: jnt_traj.duration;
  planning time: constraints + TOPPRA(...) + compute_trajectory (spline build excluded).

Prints a Markdown table; no timing asserts.

    .venv/bin/python bench/feed_vs_toppra.py [--paths P ...] [--feed F ...]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import toppra as ta
import toppra.algorithm as algo
import toppra.constraint as constraint

from machine_ctrl.model.config import load_machine
from machine_ctrl.model.kinematics import Kinematics
from trajectory.feedrate import FeedLimits
from trajectory.planner import plan

TARGET = 1.3


def toppra_plan(path, gridpoints, limits: FeedLimits):
    vl = np.r_[limits.velocity, limits.feed]                  # + virtual joint s: sdot <= F
    al = np.r_[limits.acceleration, 1e12]
    pc_vel = constraint.JointVelocityConstraint(np.column_stack((-vl, vl)))
    pc_acc = constraint.JointAccelerationConstraint(np.column_stack((-al, al)))
    instance = algo.TOPPRA([pc_vel, pc_acc], path, gridpoints=gridpoints,
                           parametrizer='ParametrizeConstAccel')
    traj = instance.compute_trajectory(0.0, 0.0)
    if traj is None:
        raise RuntimeError('TOPP-RA failed')
    return traj


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--paths', nargs='+', default=['spiral', 'helix'])
    ap.add_argument('--feed', type=float, nargs='+', default=[0.05, 1.0],
                    help='process feed limits F, m/s (1.0: effectively off, axis limits bind)')
    args = ap.parse_args()

    machine = load_machine('micromill_9axis')
    kin = Kinematics.from_config(machine)
    rows = []
    for name in args.paths:
        for feed in args.feed:
            r = plan(name, machine, feed=feed, kinematics=kin).unwrap()     # PlanError if it fails
            res = r.resolution
            path = ta.SplineInterpolator(res.s, np.column_stack((res.q, res.s)))
            lim = FeedLimits.from_machine(machine, feed=feed)
            t0 = time.perf_counter()
            traj = toppra_plan(path, r.feed.s, lim)
            t_tp = time.perf_counter() - t0
            worst = max(max(v.values()) for v in r.peak_ratios.values())
            row = dict(path=name, points=len(res.s), nodes=len(r.feed.s), feed=feed,
                       final=r.traversal_time, grid=r.feed.duration(), plan=r.planning_time,
                       passes=r.sampling.passes, scale=r.sampling.feed_scale, worst=worst,
                       tp=traj.duration, tp_plan=t_tp,
                       dev=(r.max_position_deviation, r.max_orientation_deviation))
            rows.append(row)
            print(f"{name} F = {feed:g} m/s: {row['points']} resolved points, {row['nodes']} feed "
                  f"nodes; final {row['final']:.4f} s (grid {row['grid']:.4f} s, {row['passes']} "
                  f"passes, scale {row['scale']:.4f}, max ratio {worst:.4f}), planning "
                  f"{row['plan']:.2f} s; TOPP-RA {row['tp']:.4f} s ({t_tp:.3f} s); FK deviation "
                  f"{row['dev'][0]:.1e} m / {row['dev'][1]:.1e} rad", flush=True)

    print()
    print('| path | points (feed nodes) | F (m/s) | ours: final sampled time | ours: grid time | '
          'passes / fallback scale | max FD ratio | planning | TOPP-RA v+a: time (plan) | '
          f'final / TOPP-RA | <= {TARGET}x |')
    print('|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|')
    for r in rows:
        ratio = r['final'] / r['tp']
        print(f"| {r['path']} | {r['points']} ({r['nodes']}) | {r['feed']:g} | {r['final']:.4f} s | "
              f"{r['grid']:.4f} s | {r['passes']} / {r['scale']:.3f} | {r['worst']:.4f} | "
              f"{r['plan']:.2f} s | {r['tp']:.4f} s ({r['tp_plan']:.3f} s) | {ratio:.3f} | "
              f"{'yes' if ratio <= TARGET else 'NO'} |")


if __name__ == '__main__':
    main()
