"""Planning speed, issue [5/8]: `plan helix`, `plan spiral` (default feed) and `plan helix
--feed 1` on the micromill, this tree against a baseline revision planned in the same run.

The baseline is the same planner at an earlier commit (default: the last one before the
[5/8] planning trims), checked out into a temporary git worktree and run by the same
Python, alternating with this tree run by run, so both see the same machine load. Prints
planning_time (fit + resolve + feed + sampling), resolve() alone, the local passes and the
traversal of each run, the medians and this tree's speed-up; and whether the sampled
references are bit-identical to the baseline's (they must be where the algorithm did not
change). No timing asserts.

    .venv/bin/python bench/plan_speed.py [--runs N] [--baseline REV]
"""
from __future__ import annotations

import argparse
import statistics
from pathlib import Path

from baseline import alternate, child_json, worktree

BASELINE = '8cf7d73'        # before the [5/8] planning trims (the one commit between touched a test only)
CASES = (('helix', None), ('spiral', None), ('helix', 1.0))

# one plan in a fresh process of the tree on sys.path[0]: its figures and a digest of the references
CHILD = r'''
import hashlib, json, sys, time
from machine_ctrl.model.config import load_machine
from machine_ctrl.model.kinematics import Kinematics
from trajectory.planner import plan
from trajectory.redundancy import resolve
name, feed = sys.argv[1], (float(sys.argv[2]) if sys.argv[2] != 'None' else None)
machine = load_machine('micromill_9axis')
kin = Kinematics.from_config(machine)
result = plan(name, machine, **({'feed': feed} if feed else {}), kinematics=kin).unwrap()
t0 = time.perf_counter()
resolve(result.path, kin, machine)
resolve_time = time.perf_counter() - t0
ref = result.reference
digest = hashlib.sha256(b''.join(a.tobytes() for a in (ref.position, ref.velocity, ref.acceleration))).hexdigest()
print(json.dumps({'planning': result.planning_time, 'resolve': resolve_time, 'passes': result.sampling.passes,
                  'traversal': result.traversal_time, 'samples': len(ref), 'digest': digest}))
'''


def run(tree: Path, name: str, feed) -> dict:
    return child_json(tree, CHILD, name, str(feed), what=f'plan {name}')


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--runs', type=int, default=3)
    ap.add_argument('--baseline', default=BASELINE, help=f'git revision to compare with (default {BASELINE})')
    args = ap.parse_args()
    with worktree(args.baseline) as base:
        for name, feed in CASES:
            label = f'plan {name}' + (f' --feed {feed:g}' if feed else '')

            def measure(which, tree):
                r = run(tree, name, feed)
                print(f'{label} [{which}]: planning {r["planning"]:.3f} s, resolve {r["resolve"]:.3f} s, '
                      f'{r["passes"]} passes, {r["samples"]} samples, traversal {r["traversal"]:.4f} s', flush=True)
                return r
            results = alternate(args.runs, base, measure)
            med = {w: (statistics.median(r['planning'] for r in rs), statistics.median(r['resolve'] for r in rs))
                   for w, rs in results.items()}
            same = {r['digest'] for r in results['baseline']} == {r['digest'] for r in results['this tree']}
            print(f'{label}: median planning {med["baseline"][0]:.3f} -> {med["this tree"][0]:.3f} s '
                  f'({med["baseline"][0] / med["this tree"][0]:.2f}x), resolve {med["baseline"][1]:.3f} -> '
                  f'{med["this tree"][1]:.3f} s ({med["baseline"][1] / med["this tree"][1]:.2f}x); references '
                  + ('bit-identical' if same else 'DIFFER'), flush=True)

if __name__ == '__main__':
    main()
