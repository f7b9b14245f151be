"""Planning time of trajectory.planner.plan() for a "10,000-point path" (issue [3/7]: < 10 s).

Interpretation: a path resolved at 10,000 grid steps (Δs = 20 µm, i.e. 200 mm of tool path;
the resolution, the feed optimization's node count and the number of sampled references
all scale with the path length, not with the number of CL rows). The path is the built-in
helix geometry (R = 5 mm, pitch 1 mm, 31.43 mm per turn) stretched to 6.363 turns, given
(a) with the built-in 72 CL points per turn (459 rows) and (b) as a 10,000-row CL input
(1572 points per turn). Prints, per case and run: plan()'s planning_time (fit + resolve +
feed + sampling), the wall time of the whole plan() call (adds the FK check of every
sample), the resolution's share (resolve() timed alone on the same fitted path), the
traversal time and the local re-solve passes; then the medians. No timing asserts.

    .venv/bin/python bench/plan_rate.py [--runs N] [--feed F]
"""
from __future__ import annotations

import argparse
import statistics
import time

from machine_ctrl.model.config import load_machine
from machine_ctrl.model.kinematics import Kinematics
from trajectory import toolpath
from trajectory.planner import plan
from trajectory.redundancy import resolve
from trajectory.spline import ArcLengthPath

STEPS = 10_000
TURN = 31.432e-3      # m of helix path per turn (R = 5 mm, pitch 1 mm)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--runs', type=int, default=3)
    ap.add_argument('--feed', type=float, default=0.05, help='process feed limit, m/s')
    args = ap.parse_args()
    machine = load_machine('micromill_9axis')
    kin = Kinematics.from_config(machine)
    turns = STEPS * 20e-6 / TURN
    cases = {'459 CL rows': toolpath.helix(turns=turns),
             '10,000 CL rows': toolpath.helix(turns=turns, points_per_turn=round(10_000 / turns))}
    for label, cl in cases.items():
        path = ArcLengthPath.fit(cl)
        runs = []
        for _ in range(args.runs):
            t0 = time.perf_counter()
            r = plan(cl, machine, feed=args.feed, kinematics=kin).unwrap()     # PlanError if it fails
            wall = time.perf_counter() - t0
            t0 = time.perf_counter()
            resolve(path, kin, machine)
            t_res = time.perf_counter() - t0
            runs.append((r.planning_time, wall, t_res))
            print(f'{label} ({len(cl)} rows, {path.length * 1e3:.1f} mm, {len(r.resolution.s)} '
                  f'resolved points, {len(r.feed.s)} feed nodes, {len(r.reference)} samples): '
                  f'planning {r.planning_time:.2f} s, plan() wall {wall:.2f} s, resolve alone '
                  f'{t_res:.2f} s; traversal {r.traversal_time:.4f} s, {r.sampling.passes} passes',
                  flush=True)
        med = [statistics.median(x) for x in zip(*runs)]
        print(f'{label}: median of {args.runs}: planning {med[0]:.2f} s, plan() wall {med[1]:.2f} s, '
              f'resolve {med[2]:.2f} s')


if __name__ == '__main__':
    main()
