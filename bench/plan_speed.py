"""Planning speed, issue [5/8]: `plan helix`, `plan spiral` (default feed) and `plan helix
--feed 1` on the micromill, this tree against a baseline revision planned in the same run.

The baseline is the same planner at an earlier commit (default: the last one before the
[5/8] planning trims), checked out into a temporary git worktree and run by the same
Python, alternating with this tree run by run, so both see the same machine load. Prints
planning_time (fit + resolve + feed + sampling) of the first plan in a fresh process (what
`machine-ctrl plan` reports, loading numba's compiled kernel included), the wall time of that
plan() call (planning_time plus the planner's final check of the sampled references against
the path, which a caller waits for too) and planning_time of a second plan
in the same process (what the trajectory node's planner process, warmed at its start, pays),
resolve() alone, the local passes, the traversal and the tool's peak speed over the feed
limit (chords of the sent positions' forward kinematics over a period) of each run, the medians and this
tree's speed-up; and the largest difference of the sampled references from the baseline's
(0: bit-identical, as they must be where the algorithm did not change). No timing asserts.

    .venv/bin/python bench/plan_speed.py [--runs N] [--baseline REV]
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

import numpy as np

from baseline import alternate, child_json, worktree

BASELINE = '8cf7d73'        # before the [5/8] planning trims (the one commit between touched a test only)
CASES = (('helix', None), ('spiral', None), ('helix', 1.0))

# one plan in a fresh process of the tree on sys.path[0]: its figures and a digest of the references
CHILD = r'''
import json, sys, time
import numpy as np
from machine_ctrl.model.config import load_machine
from machine_ctrl.model.kinematics import Kinematics
from trajectory.planner import DEFAULT_FEED, plan
from trajectory.redundancy import resolve
name, feed, out = sys.argv[1], (float(sys.argv[2]) if sys.argv[2] != 'None' else None), sys.argv[3]
machine = load_machine('micromill_9axis')
kin = Kinematics.from_config(machine)
t0 = time.perf_counter()
result = plan(name, machine, **({'feed': feed} if feed else {}), kinematics=kin).unwrap()
call = time.perf_counter() - t0
again = plan(name, machine, **({'feed': feed} if feed else {}), kinematics=kin).unwrap().planning_time
t0 = time.perf_counter()
resolve(result.path, kin, machine)
resolve_time = time.perf_counter() - t0
ref = result.reference
tip, _ = kin.forward_many(ref.position)          # the tool's speed over each period, by its chords
tool_feed = float(np.max(np.linalg.norm(np.diff(tip, axis=0), axis=1)) / ref.period / (feed or DEFAULT_FEED))
np.savez(out, position=ref.position, velocity=ref.velocity, acceleration=ref.acceleration)
print(json.dumps({'planning': result.planning_time, 'call': call, 'again': again, 'resolve': resolve_time,
                  'passes': result.sampling.passes, 'traversal': result.traversal_time, 'samples': len(ref),
                  'tool_feed': tool_feed}))
'''


def run(tree: Path, name: str, feed, out: Path) -> dict:
    return child_json(tree, CHILD, name, str(feed), str(out), what=f'plan {name}')


def difference(a: Path, b: Path) -> str:
    """The largest difference of two runs' references, per quantity (or why none)."""
    with np.load(a) as x, np.load(b) as y:
        if x['position'].shape != y['position'].shape:
            return f'{len(x["position"])} vs {len(y["position"])} samples'
        return ', '.join(f'{k} {np.abs(x[k] - y[k]).max():.2g}' for k in ('position', 'velocity', 'acceleration'))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--runs', type=int, default=3)
    ap.add_argument('--baseline', default=BASELINE, help=f'git revision to compare with (default {BASELINE})')
    args = ap.parse_args()
    with worktree(args.baseline) as base, tempfile.TemporaryDirectory() as tmp:
        for name, feed in CASES:
            label = f'plan {name}' + (f' --feed {feed:g}' if feed else '')
            runs = []

            def measure(which, tree):
                out = Path(tmp) / f'{which.replace(" ", "_")}-{len(runs)}.npz'
                r = dict(run(tree, name, feed, out), out=out)
                runs.append(r)
                print(f'{label} [{which}]: planning {r["planning"]:.3f} s (the call {r["call"]:.3f} s, again '
                      f'{r["again"]:.3f} s), resolve '
                      f'{r["resolve"]:.3f} s, {r["passes"]} passes, {r["samples"]} samples, traversal '
                      f'{r["traversal"]:.4f} s, the tool at {r["tool_feed"]:.4f} of the feed limit at its peak', flush=True)
                return r
            results = alternate(args.runs, base, measure)
            med = {w: {k: statistics.median(r[k] for r in rs) for k in ('planning', 'call', 'again', 'resolve')}
                   for w, rs in results.items()}
            b, t = med['baseline'], med['this tree']
            print(f'{label}: median planning {b["planning"]:.3f} -> {t["planning"]:.3f} s '
                  f'({b["planning"] / t["planning"]:.2f}x), the call {b["call"]:.3f} -> {t["call"]:.3f} s, '
                  f'again {b["again"]:.3f} -> {t["again"]:.3f} s '
                  f'({b["again"] / t["again"]:.2f}x), resolve {b["resolve"]:.3f} -> {t["resolve"]:.3f} s '
                  f'({b["resolve"] / t["resolve"]:.2f}x); references against the baseline: largest difference '
                  + difference(results['baseline'][0]['out'], results['this tree'][0]['out']), flush=True)


if __name__ == '__main__':
    main()
