"""Feed optimization ([3/7] trajectory.feedrate.optimize_feed) against TOPP-RA (toppra) on the
built-in spiral and helix, resolved on the 9-axis micromill. Issue [3/7] target: our
(jerk-limited) traversal time <= 1.3 x TOPP-RA's time with velocity and acceleration limits
only (TOPP-RA has no jerk limit: a lower bound).

Per path: builtin(name) -> ArcLengthPath.fit -> redundancy.resolve (q, q', q'', q''' on a
uniform s grid of step --step) -> both planners on the same uniform subgrid of --nodes
nodes (the resolved derivatives are interpolated linearly onto it):

* ours, jerk-limited: optimize_feed(s_sub, dq, ddq, dddq, FeedLimits.from_machine(m, F));
* ours without jerk: the same with every jerk limit set to 1e12 (the jerk rows and the
  rest-end jerk envelope become inactive);
* TOPP-RA 0.6: ta.SplineInterpolator(s, [q, s]) through the full-resolution resolved q
  (cubic, not-a-knot), gridpoints = the same subgrid, JointVelocityConstraint +
  JointAccelerationConstraint (default Interpolation discretization) with the same per-axis
  limits, parametrizer ParametrizeConstAccel, rest to rest. The process feed limit F on
  sdot (s is arc length) is a "virtual joint" equal to s, appended to q, with velocity
  limit F and an inactive acceleration limit.

Times: ours = FeedProfile.duration() (sum 2 ds / (sdot_i + sdot_i+1) on the grid);
TOPP-RA = jnt_traj.duration (the same formula on its sdot grid, constant sddot per
segment). Planning time: best of --repeat wall-clock runs of the planner call alone
(TOPP-RA: constraints + TOPPRA(...) + compute_trajectory; the spline build is excluded,
as is our grid interpolation). Prints a Markdown table; no timing asserts.

    .venv/bin/python bench/feed_vs_toppra.py [--feed F ...] [--nodes N] [--step DS] [--repeat R]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import toppra as ta
import toppra.algorithm as algo
import toppra.constraint as constraint

from machine_ctrl.config import load_machine
from machine_ctrl.kinematics import Kinematics
from trajectory import toolpath
from trajectory.feedrate import FeedLimits, accelerations, jerks, optimize_feed
from trajectory.redundancy import RedundancySettings, resolve
from trajectory.spline import ArcLengthPath

TARGET = 1.3
NO_JERK = 1e12


def subgrid(res, nodes):
    """Uniform subgrid of <= nodes nodes over [0, S], derivatives interpolated linearly."""
    m = min(nodes, len(res.s))
    s = np.linspace(0.0, res.s[-1], m)
    out = [np.column_stack([np.interp(s, res.s, a[:, i]) for i in range(a.shape[1])])
           for a in (res.dq, res.ddq, res.dddq)]
    return s, out


def best_of(repeat, fn):
    best, value = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        value = fn()
        best = min(best, time.perf_counter() - t0)
    return best, value


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
    return instance, traj


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--paths', nargs='+', default=['spiral', 'helix'])
    ap.add_argument('--feed', type=float, nargs='+', default=[0.05, 1.0],
                    help='process feed limits F, m/s (1.0: effectively off, axis limits bind)')
    ap.add_argument('--nodes', type=int, default=1000)
    ap.add_argument('--step', type=float, default=20e-6, help='redundancy resolution step, m')
    ap.add_argument('--repeat', type=int, default=3)
    args = ap.parse_args()

    machine = load_machine('micromill_9axis')
    kin = Kinematics.from_config(machine)
    rows = []
    for name in args.paths:
        cl = toolpath.builtin(name)
        fitted = ArcLengthPath.fit(cl)
        t0 = time.perf_counter()
        res = resolve(fitted, kin, machine, RedundancySettings(step=args.step))
        t_res = time.perf_counter() - t0
        print(f'{name}: {len(cl)} CL points, S = {fitted.length * 1e3:.1f} mm, resolved '
              f'{len(res.s)} points (ds = {args.step * 1e6:g} um) in {t_res:.1f} s, max error '
              f'{res.max_position_error:.1e} m / {res.max_orientation_error:.1e} rad', flush=True)
        s, (dq, ddq, dddq) = subgrid(res, args.nodes)
        ds = s[1] - s[0]
        # TOPP-RA's path: cubic spline through the full-resolution q, plus the virtual joint s
        path = ta.SplineInterpolator(res.s, np.column_stack((res.q, res.s)))
        d1, d2 = path(s, 1)[:, :-1], path(s, 2)[:, :-1]
        scale1, scale2 = np.abs(dq).max(axis=0), np.abs(ddq).max(axis=0)
        away = (s > 1e-3) & (s < s[-1] - 1e-3)     # past the nullspace start transient
        err = [np.max(np.abs(d - r)[mask] / np.maximum(sc, 1e-300))
               for mask in (slice(1, -1), away) for d, r, sc in ((d1, dq, scale1), (d2, ddq, scale2))]
        print(f'  subgrid {len(s)} nodes (ds = {ds * 1e6:.1f} um); TOPP-RA spline vs resolved '
              f"q', q'' (rel. to axis max): {err[0]:.1e}, {err[1]:.1e} over all interior nodes, "
              f'{err[2]:.1e}, {err[3]:.1e} over 1 mm < s < S - 1 mm', flush=True)
        for feed in args.feed:
            lim = FeedLimits.from_machine(machine, feed=feed)
            free = FeedLimits(lim.velocity, lim.acceleration, np.full_like(lim.jerk, NO_JERK), feed)
            t_ours, prof = best_of(args.repeat, lambda: optimize_feed(s, dq, ddq, dddq, lim))
            t_free, prof_free = best_of(args.repeat, lambda: optimize_feed(s, dq, ddq, dddq, free))
            t_tp, (inst, traj) = best_of(args.repeat, lambda: toppra_plan(path, s, lim))
            # checks on the grid (our operators): worst ratio to the limits
            def worst(b):
                v = np.max(np.abs(dq) * np.sqrt(b)[:, None] / lim.velocity)
                a = np.max(np.abs(accelerations(b, dq, ddq, ds)) / lim.acceleration)
                j = np.max(np.abs(jerks(b, dq, ddq, dddq, ds)) / lim.jerk)
                return v, a, j, np.sqrt(b.max()) / feed
            sd = np.asarray(inst.problem_data.sd_vec)
            b_tp = sd ** 2
            row = dict(path=name, points=len(res.s), nodes=len(s), feed=feed,
                       ours=prof.duration(), ours_plan=t_ours, it=prof.iterations,
                       free=prof_free.duration(), free_plan=t_free,
                       tp=traj.duration, tp_plan=t_tp,
                       tp_grid=float(np.sum(2 * np.diff(s) / (sd[:-1] + sd[1:]))),
                       w_ours=worst(prof.b), w_free=worst(prof_free.b), w_tp=worst(b_tp))
            rows.append(row)
            print(f"  F = {feed:g} m/s: ours {row['ours']:.4f} s ({t_ours:.2f} s, "
                  f"{prof.iterations} LPs), no jerk {row['free']:.4f} s ({t_free:.2f} s), "
                  f"TOPP-RA {row['tp']:.4f} s ({t_tp:.3f} s; grid formula {row['tp_grid']:.4f} s)",
                  flush=True)
            for key, label in (('w_ours', 'ours'), ('w_free', 'ours no jerk'), ('w_tp', 'TOPP-RA')):
                v, a, j, f = row[key]
                print(f'    {label:13s} max |v|/v_max {v:.3f}, |a|/a_max {a:.3f}, '
                      f'|j|/j_max {j:.2f}, sdot/F {f:.3f}  (our grid operators)')

    print()
    print('| path | points (nodes) | F (m/s) | ours, jerk-limited: time (plan) | ours, no jerk '
          'limit: time (plan) | TOPP-RA v+a: time (plan) | ours / TOPP-RA | ours no jerk / '
          f'TOPP-RA | <= {TARGET}x |')
    print('|---|---:|---:|---:|---:|---:|---:|---:|---|')
    for r in rows:
        ratio = r['ours'] / r['tp']
        print(f"| {r['path']} | {r['points']} ({r['nodes']}) | {r['feed']:g} | "
              f"{r['ours']:.4f} s ({r['ours_plan']:.2f} s) | {r['free']:.4f} s ({r['free_plan']:.2f} s) | "
              f"{r['tp']:.4f} s ({r['tp_plan']:.3f} s) | {ratio:.3f} | {r['free'] / r['tp']:.3f} | "
              f"{'yes' if ratio <= TARGET else 'NO'} |")


if __name__ == '__main__':
    main()
