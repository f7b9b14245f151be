"""Node start, the import part: how long a fresh Python takes to import each node's module
(what every `ros2 run`, launch and graph test pays before rclpy even starts), this tree
against a baseline revision measured in the same run, alternating run by run so that both
see the same machine load. Also counts the scipy modules each import pulls in. No timing
asserts.

    .venv/bin/python bench/node_start.py [--runs N] [--baseline REV]
"""
from __future__ import annotations

import argparse
import statistics
from pathlib import Path

from baseline import alternate, child_json, worktree

BASELINE = 'ab7fb23'        # before the import trims (scipy.signal, scipy.optimize, the law registry)
NODES = ('hw_sim_node', 'servo_node', 'dual_stage_node', 'trajectory_node', 'contour_error_node')

CHILD = r'''
import json, sys, time
t0 = time.perf_counter()
__import__('machine_ctrl.ros.' + sys.argv[1])
took = time.perf_counter() - t0
print(json.dumps({'seconds': took, 'scipy': sum(1 for m in sys.modules if m.startswith('scipy'))}))
'''


def measure(tree: Path, node: str) -> dict:
    return child_json(tree, CHILD, node, what=f'the import of {node}')


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--runs', type=int, default=7)
    ap.add_argument('--baseline', default=BASELINE, help=f'git revision to compare with (default {BASELINE})')
    args = ap.parse_args()
    with worktree(args.baseline) as base:
        total = {'baseline': 0.0, 'this tree': 0.0}
        for node in NODES:
            results = alternate(args.runs, base, lambda which, tree: measure(tree, node))
            med = {w: statistics.median(r['seconds'] for r in rs) for w, rs in results.items()}
            scipy = {w: rs[0]['scipy'] for w, rs in results.items()}
            for w in total:
                total[w] += med[w]
            print(f'import {node}: median {med["baseline"]:.3f} -> {med["this tree"]:.3f} s '
                  f'({med["baseline"] - med["this tree"]:+.3f} s saved), scipy modules {scipy["baseline"]} -> '
                  f'{scipy["this tree"]}', flush=True)
        print(f'all five nodes: {total["baseline"]:.3f} -> {total["this tree"]:.3f} s of imports '
              f'({args.runs} runs each, medians)')

if __name__ == '__main__':
    main()
